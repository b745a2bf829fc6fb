"""Every screen that can refuse a file passes the valid real recordings it was not built for.

The recordings are the UNDCMotor lab's own (tests/data/undcmotor) and faithful synthetic ones
(tests/real_like.py: a coarse encoder read on a jittered clock, commutator ripple, a logger's
start-up, a robot loop's jitter and the pauses between SysId tests), whose plant is known.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from identify import fit
from identify.checks.screening import RunStartWarning
from identify.data import ConstantInputTurnWarning, as_recordings, check_constant_input_runs
from identify.errors import NotIdentifiableError
from motorsim import Motor, Recording
from motorsim.columns import import_recording
from motorsim.plant import simulate
from tests.real_like import FLY_A, FLY_B, LAB_A, LAB_B, lab_run, sysid_tests, write_lab_csv

UNDC = Path(__file__).resolve().parents[1] / "data" / "undcmotor"


def _lab(volts: np.ndarray, **kwargs) -> Recording:
    t, speed = lab_run(volts, **kwargs)
    return Recording.from_columns(time=t, duty=volts, speed=speed, input_unit="V")


def _step(share: float, n: int = 3000) -> np.ndarray:
    u = np.zeros(3 * n)
    u[n:2 * n] = share * 12.0
    return u


# --- the constant-input screen ----------------------------------------------------------------------

@pytest.mark.parametrize("share", [0.2, 0.4, 0.6])
def test_a_real_step_response_is_no_turn_under_a_constant_input(share):
    # measured before the smoothing: 'rises by 46.3 and falls by 13.8 rad/s' refused the 20 % step (its fall is
    # the encoder's rounding on a jittered clock, a count either way); smoothed its fall is 0.05 rad/s
    rec = _lab(_step(share))
    check_constant_input_runs(rec, "step")


def test_a_small_step_on_a_coarse_encoder_is_no_turn():
    # the UNDCMotor kind: 50 Hz, steps of 0.112 rad/s from the encoder, a step of 0.1 V (1.7 rad/s): the
    # rounding flips a step or two either way, more than 10 % of the range
    rec = _lab(np.r_[np.full(100, 2.0), np.full(200, 2.1)], dt=0.02, counts_per_rev=2800, ripple=0.0)
    check_constant_input_runs(rec, "small step")


@pytest.mark.parametrize("name", ["DCmotor_step_open_exp.csv", "DCmotor_prbs_open_exp.csv"])
def test_the_lab_recordings_pass_the_constant_input_screen(name):
    rec = import_recording(UNDC / name, time="t:s", input="u:V", speed="y:deg/s")
    for delay in (0, 1):
        check_constant_input_runs(rec, name, delay)


def _clipped_sine(clip: float) -> Recording:
    t = np.arange(800) * 0.005
    applied = 200 * np.sin(10.0 * t)
    speed = simulate(Motor(25.0, 3.0), applied, t).speed
    return Recording(time=t, duty=np.clip(np.round(applied), -clip, clip), sample_period=0.005, speed=speed)


def test_a_log_clipped_below_what_the_motor_received_is_still_refused():
    with pytest.raises(NotIdentifiableError, match=r"rises by .* and falls by .* \(and in \d+ more such runs\)"):
        check_constant_input_runs(_clipped_sine(60), "clipped")


def test_one_run_that_sags_a_little_is_said_and_the_fit_goes_on():
    # a step whose speed sags by 15 % of its range late in the run (a supply that sags): said, not refused
    t = np.arange(3000) * 1e-3
    u = np.r_[np.zeros(500), np.full(2500, 6.0)]
    speed = simulate(Motor(LAB_A, LAB_B), u, t).speed
    speed *= np.where(t > 2.0, 1 - 0.15 * np.minimum((t - 2.0) / 0.5, 1.0), 1.0)
    rec = Recording(time=t, duty=u, sample_period=1e-3, speed=speed)
    with pytest.warns(ConstantInputTurnWarning, match=r"rises by .* falls by .*, 15 % of its range, in this one "
                                                      "run"):
        check_constant_input_runs(rec, "sag")


def test_the_default_answers_a_real_step_and_covers_the_truth():
    rec = _lab(_step(0.4))
    est = fit(rec)
    assert est.confidence_interval()["a"][0] <= LAB_A <= est.confidence_interval()["a"][1]
    assert est.confidence_interval()["b"][0] <= LAB_B <= est.confidence_interval()["b"][1]


# --- isolated residual outliers -----------------------------------------------------------------------

def test_a_chirps_first_samples_are_left_out_and_said_not_refused(tmp_path):
    t = np.arange(12000) * 1e-3
    chirp = np.round(6 + 3 * np.sin(2 * np.pi * (0.2 + 10 * t / t[-1]) * t), 4)
    path = write_lab_csv(tmp_path / "chirp.csv", chirp, startup=True, initial_speed=100.0)
    with pytest.warns(UserWarning):
        rec = import_recording(path, time="time:s", input="voltage:V", speed="speed_rad_s")
    with pytest.warns(RunStartWarning, match=r"the first samples of a run \(seq 1\)"):
        est = fit(rec)
    assert est.confidence_interval()["a"][0] <= LAB_A <= est.confidence_interval()["a"][1]


def test_an_outlier_inside_a_run_is_still_refused():
    t = np.arange(3000) * 1e-3
    chirp = np.round(6 + 3 * np.sin(2 * np.pi * (0.2 + 10 * t / t[-1]) * t), 4)
    speed = simulate(Motor(LAB_A, LAB_B), chirp, t).speed + np.random.default_rng(0).normal(0, 0.05, len(t))
    speed[1500] += 20.0
    rec = Recording(time=t, duty=chirp, sample_period=1e-3, speed=speed, metadata={"input_unit": "V"})
    with pytest.raises(ValueError, match="seq 1500"):
        fit(rec)


# --- SysId: tests of one loop, jittered, apart ------------------------------------------------------

def _sysid_recordings(seed: int = 3) -> list[Recording]:
    recs = []
    for _, t, u, w in sysid_tests(seed=seed):
        with pytest.warns(UserWarning, match="not uniform"):
            recs.append(Recording.from_columns(time=t, duty=u, speed=w, input_unit="V"))
    return recs


def test_the_four_tests_of_a_routine_pool_though_their_periods_differ_by_microseconds():
    recs = _sysid_recordings()
    periods = sorted(r.sample_period for r in recs)
    assert periods[0] != periods[-1] and periods[-1] / periods[0] - 1 < 5e-3     # medians of a jittered clock
    with pytest.warns(UserWarning, match=r"sample periods differ by up to .* pooled at"):
        pooled = as_recordings(recs)
    assert len({r.sample_period for r in pooled}) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        est = fit(recs)
    # the flywheel a = 8, b = 66.7, within 3 standard errors (0.05 rad/s of white noise, fixed seed)
    assert abs(est.a - FLY_A) <= 3 * est.stderr()["a"] and abs(est.b - FLY_B) <= 3 * est.stderr()["b"]


def test_periods_that_differ_by_more_than_a_jittered_clock_are_still_refused():
    t = np.arange(400) * 0.005
    u = np.sign(np.sin(3 * t))
    recs = [Recording(time=t * f, duty=u, sample_period=0.005 * f, speed=simulate(Motor(8, 60), u, t * f).speed)
            for f in (1.0, 1.02)]
    with pytest.raises(ValueError, match=r"must share one sample_period \(within 0.5 %, or the jitter of their"):
        as_recordings(recs)


def test_a_pause_on_a_jittered_clock_cuts_the_runs_apart():
    (_, t1, u1, w1), (_, t2, u2, w2), *_ = sysid_tests(seed=1)
    with pytest.warns(UserWarning, match=r"1 pause\(s\) longer than 4 periods cut it into runs"):
        rec = Recording.from_columns(time=np.r_[t1, t2], duty=np.r_[u1, u2], speed=np.r_[w1, w2], input_unit="V")
    assert len(rec.segments()) == 2 and rec.metadata["time_pauses"] == "1"
    # the pause is a gap of as many periods as it lasted, not one sample
    gap = int(rec.seq[len(t1)] - rec.seq[len(t1) - 1])
    assert gap == round((t2[0] - t1[-1]) / rec.sample_period)


def test_a_jittered_sysid_wpilog_is_answered_by_the_default(tmp_path, capsys):
    pytest.importorskip("wpiutil", reason="robotpy-wpiutil (the wpilib extra) is not installed")
    from motorid.cli import main
    from tests.real_like import write_sysid_wpilog
    path = write_sysid_wpilog(tmp_path / "sysid.wpilog")
    # before: 'internal error: OverflowError: math range error' (the pauses held the last voltage in one run)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        status = main(["identify", str(path), "--time", "time_s", "--input", "voltage-drive", "--speed",
                       "velocity-drive", "--json"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    import json
    doc = json.loads(captured.out)
    # within 3 standard errors (0.05 rad/s of white noise, fixed seed)
    assert abs(doc["a"] - FLY_A) <= 3 * doc["a_stderr"] and abs(doc["b"] - FLY_B) <= 3 * doc["b_stderr"]
    assert "3 pause(s)" in captured.err
    assert math.isfinite(doc["b"])


# --- one SysId test alone -------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("test", [0, 1, 2, 3], ids=["quasistatic-forward", "quasistatic-reverse", "dynamic-forward",
                                                    "dynamic-reverse"])
def test_one_sysid_test_alone_is_answered_not_clear_and_covering(seed, test):
    # before: a dynamic test alone was refused ('input is constant (7 V throughout): ... not persistently
    # exciting'); the transient from rest fixes a, and b only up to a friction the one level cannot show
    _, t, u, w = sysid_tests(seed=seed)[test]
    with pytest.warns(UserWarning, match="not uniform"):
        rec = Recording.from_columns(time=t, duty=u, speed=w, input_unit="V")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        est = fit(rec)
    ci = est.confidence_interval()
    assert not est.selection.clear
    assert ci["a"][0] <= FLY_A <= ci["a"][1] and ci["b"][0] <= FLY_B <= ci["b"][1]


def _dynamic_test(friction: float, seed: int = 1, level: float = 7.0) -> Recording:
    rng = np.random.default_rng(seed)
    t = np.arange(500) * 0.005
    u = np.full(500, level)
    speed = simulate(Motor(FLY_A, FLY_B, friction=friction), u, t).speed + rng.normal(0, 0.05, 500)
    return Recording(time=t, duty=u, sample_period=0.005, speed=speed, metadata={"input_unit": "V"})


@pytest.mark.parametrize("friction", [0.0, 20.0, 60.0])
def test_a_dynamic_test_alone_leaves_b_open_on_the_side_friction_moves_it(friction):
    # one level u fixes b u - c, not b: with kS = 0.3 and 0.9 V of friction the linear fit's b is 4 % and 13 %
    # low, so b's interval is open upwards and kS, kV hold what a friction would make them
    from identify.data import ConstantInputWarning
    from identify.feedforward import feedforward_constants
    with pytest.warns(ConstantInputWarning, match=r"input is constant \(7 V throughout\)"):
        est = fit(_dynamic_test(friction))
    ci = est.confidence_interval()
    assert est.structure == "linear" and not est.selection.clear
    assert ci["b"][1] == math.inf and ci["b"][0] <= FLY_B
    assert ci["a"][0] <= FLY_A <= ci["a"][1]
    assert any("one input level (7 V)" in n for n in est.notes)
    ff = feedforward_constants(est).confidence_interval()
    assert ff["kv"][0] <= FLY_A / FLY_B <= ff["kv"][1]
    assert ff["ka"][0] <= 1 / FLY_B <= ff["ka"][1]
    assert ff["ks"][0] <= friction / FLY_B <= ff["ks"][1]


def test_a_constant_input_the_motor_had_settled_at_is_still_refused():
    # no transient: the speed holds only b u / a, and a, b cannot be separated
    rec = _dynamic_test(0.0)
    settled = Recording(time=rec.time, duty=rec.duty, sample_period=0.005,
                        speed=FLY_B / FLY_A * 7.0 + np.random.default_rng(0).normal(0, 0.05, 500),
                        metadata={"input_unit": "V"})
    with pytest.raises(NotIdentifiableError, match=r"input is constant \(7 V throughout\) and the speed holds no "
                                                   "transient"):
        fit(settled)
