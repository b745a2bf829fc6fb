"""A SysId dynamic test alone: are `a`'s intervals calibrated, or too narrow?

Its 95 % interval missed the flywheel's `a` on 3 of 30 tests (seeds 0-14, forward and reverse).  Over 100
(seeds 0-49) it missed on 5, the errors in standard errors had an RMS of 1.006 and a mean of -0.01: the
stated errors are right and 5 % misses are what a 95 % interval owes; widening it would make it wrong the
other way.  This test holds that calibration on 40 tests.
"""
from __future__ import annotations

import warnings

import numpy as np

from identify import fit
from motorsim import Recording
from tests.real_like import FLY_A, sysid_tests


def test_a_dynamic_tests_errors_in_a_are_its_stated_standard_errors():
    z = []
    for seed in range(20):
        for _, t, u, w in sysid_tests(seed=seed)[2:]:              # dynamic forward and reverse
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                est = fit(Recording.from_columns(time=t, duty=u, speed=w, input_unit="V"))
            z.append((est.a - FLY_A) / est.stderr()["a"])
    z = np.asarray(z)
    # 40 errors of unit variance: their RMS is 1 within about 0.11 (one standard deviation) and their mean 0
    # within 0.16; the bounds are three of those, far from a standard error off by a third either way
    assert 0.75 <= np.sqrt(np.mean(z**2)) <= 1.35, z.round(2)
    assert abs(z.mean()) <= 0.5, z.round(2)
