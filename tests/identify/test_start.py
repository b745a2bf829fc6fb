"""Start values of the iterative estimators, against a dense least-squares reference."""
import math

import numpy as np
import pytest

from identify.data import prepare_segments
from identify.fits.sensitivity import zoh_response
from identify.fits.start import grid_guess
from motorsim import Encoder, Experiment, Motor, SimRig, Sine


def _dense_grid_guess(segments):
    # reference: one least-squares problem in b and every segment's initial speed (and angle offset)
    dt = float(np.median(np.concatenate([np.diff(s.time) for s in segments])))
    span = max(s.time[-1] - s.time[0] for s in segments)
    best = (math.inf, 1.0, 1.0)
    for a in np.geomspace(0.5 / span, 2.0 / dt, 40):
        blocks, ys = [], []
        for i, seg in enumerate(segments):
            resp = zoh_response(a, 1.0, seg.drive, seg.time, 0.0, uniform=seg.uniform)
            block = np.zeros((len(seg.time), 1 + 2 * len(segments)))
            block[:, 0] = resp.angle
            block[:, 1 + 2 * i] = resp.angle_sensitivity[:, 2]
            block[:, 2 + 2 * i] = 1.0
            blocks.append(block)
            ys.append(seg.output)
        A, y = np.vstack(blocks), np.concatenate(ys)
        sol, *_ = np.linalg.lstsq(A, y, rcond=None)
        rss = float(np.sum((y - A @ sol) ** 2))
        if rss < best[0]:
            best = (rss, float(a), float(sol[0]))
    return best[1], best[2]


@pytest.mark.parametrize("drop_rate", [0.0, 0.03])
def test_grid_guess_is_the_dense_least_squares_solution(drop_rate):
    rig = SimRig(Motor(25.0, 3.0), Encoder(360, angle_noise=1e-3), drop_rate=drop_rate, rng=np.random.default_rng(2))
    segments = prepare_segments([rig.run(Experiment(Sine(20.0, 150), 0.005, 3.0))], 0)
    assert (len(segments) > 5) == (drop_rate > 0)
    a, b = grid_guess(segments)
    a_ref, b_ref = _dense_grid_guess(segments)
    assert a == a_ref                                  # the same grid point wins
    assert b == pytest.approx(b_ref, rel=1e-9)         # b from two exact solutions of one problem


def test_the_regression_guess_is_kept_with_its_recording(monkeypatch):
    # found once per recording (the default asks for it at every input delay) and kept with it: a recording
    # that has been fitted still pickles (a sweep sends it to its workers); pooled recordings keep nothing
    import pickle

    from identify.fits import start
    runs = [SimRig(Motor(a, 3.0), Encoder(360, angle_noise=1e-3), rng=np.random.default_rng(a)).run(
        Experiment(Sine(20.0, 150), 0.005, 2.0)) for a in (10, 25)]
    fresh = [start._regression_guess([r]) for r in runs] + [start._regression_guess(runs)]
    assert len(set(fresh)) == 3                                    # three different answers to tell apart
    computed = []
    compute = start._regression_guess
    monkeypatch.setattr(start, "_regression_guess", lambda recs: computed.append(len(recs)) or compute(recs))
    for _ in range(3):
        assert [start.regression_guess([r]) for r in runs] + [start.regression_guess(runs)] == fresh
    assert computed == [1, 1, 2, 2, 2]            # each recording once, the pooled pair every time
    again = pickle.loads(pickle.dumps(runs[0]))
    assert start.regression_guess([again]) == fresh[0] and computed[-1] == 2
