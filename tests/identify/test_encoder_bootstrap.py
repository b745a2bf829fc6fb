"""The linearised encoder bootstrap's phase sums equal the product with the floored angles they replace."""
import numpy as np
import pytest

from identify.encoder_bootstrap import rounding_steps


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
