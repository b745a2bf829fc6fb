"""The linearised encoder bootstrap's phase sums equal the product with the floored angles they replace."""
import numpy as np
import pytest

from identify.checks.encoder_bootstrap import rounding_steps


@pytest.mark.parametrize("runs", [1, 7, 64], ids=["one", "seven", "sixty-four"])
def test_rounding_steps_equal_the_floors_at_every_phase(runs):
    rng = np.random.default_rng(5)
    counts = rng.uniform(-3000.0, 3000.0, 2000)
    counts[:10] = np.round(counts[:10])          # samples exactly on a count: never round up
    weights = rng.normal(size=(3, len(counts)))
    phases = (np.arange(runs) + 0.5) / runs
    direct = weights @ (np.floor(counts[:, None] + phases) - np.floor(counts)[:, None])
    # both sum ~1000 weights of size 1: they agree to rounding, ~1e-13 of the sum's size
    np.testing.assert_allclose(rounding_steps(weights, counts, runs), direct, rtol=0, atol=1e-10)


def test_a_nuisance_column_the_data_do_not_see_leaves_the_covariance_unchanged():
    # a segment's initial speed while the shaft starts stuck by friction has an all-zero Jacobian column
    from identify.checks.encoder_bootstrap import linearised_encoder_bootstrap_covariance
    from identify.data import Segment
    rng = np.random.default_rng(3)
    n, step = 500, 2 * np.pi / 4096
    t = np.arange(n) * 0.005
    model = np.cumsum(rng.normal(0.0, 3 * step, n))
    seg = Segment(time=t, drive=np.zeros(n), output=model, kind="angle", uniform=True, recording=0, start=0)
    J = rng.normal(size=(n, 3))
    J -= J.mean(axis=0)
    seen = linearised_encoder_bootstrap_covariance([seg], [model], [step], 2 * step ** 2 / 12, J, 2)
    padded = np.column_stack([J, np.zeros(n)])
    with_unseen = linearised_encoder_bootstrap_covariance([seg], [model], [step], 2 * step ** 2 / 12, padded, 2)
    assert np.all(np.isfinite(seen))
    # the same arithmetic on the same columns: equal to rounding
    np.testing.assert_allclose(with_unseen, seen, rtol=1e-12, atol=0)
