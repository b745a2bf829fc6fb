import math

import numpy as np
import pytest

from motorsim import Encoder, backward_difference, counts_to_angle


def test_counts_are_the_floor_of_the_angle_in_counts_plus_offset():
    enc = Encoder(counts_per_rev=1000, count_offset=7)
    angle = np.array([0.0, 2 * math.pi / 1000 * 0.999, 2 * math.pi / 1000, -1e-12, 2 * math.pi])
    assert enc.counts(angle).tolist() == [7, 7, 8, 6, 1007]


def test_noise_needs_an_rng_and_is_reproducible():
    enc = Encoder(1000, angle_noise=0.01)
    with pytest.raises(TypeError, match="rng must be a numpy.random.Generator"):
        enc.counts(np.zeros(3))
    a = enc.counts(np.zeros(1000), np.random.default_rng(3))
    b = enc.counts(np.zeros(1000), np.random.default_rng(3))
    np.testing.assert_array_equal(a, b)
    # std of counts ~ 0.01 rad * 1000/(2 pi) = 1.59 counts (plus quantisation); within 10 % at n=1000
    assert abs(a.std() - math.hypot(0.01 * 1000 / (2 * math.pi), math.sqrt(1 / 12))) < 0.16


def test_backward_difference_is_the_average_speed_over_the_previous_interval():
    t = np.array([0.0, 0.1, 0.3, 0.4])
    theta = np.array([0.0, 1.0, 2.0, 5.0])
    np.testing.assert_allclose(backward_difference(theta, t), [np.nan, 10.0, 5.0, 30.0])
    np.testing.assert_allclose(counts_to_angle([0, 250, -500], 1000), [0, math.pi / 2, -math.pi])


def test_encoder_rejects_bad_resolution():
    with pytest.raises(ValueError, match="counts_per_rev must be in 1"):
        Encoder(0)
