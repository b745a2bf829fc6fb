"""Feedback is recognised from the loop, not from the clock: irregular timing in open loop never makes a loop.

Two ways a clock reaches both signals of an open-loop run at once, written here sample by sample with the
exact zero-order-hold simulation of :func:`motorsim.plant.simulate`:

* firmware that computes its waveform from its own clock: each sample is taken a random fraction of a
  period early or late, and the duty is the waveform at that instant (so it moves with the jitter) while
  the shaft is read at that instant too (so it moves with it as well);
* samples lost from a file without ``seq``: the row after the loss has jumped two periods in both.

Before the test took the clock out, such runs read as a duty answering the output (shares up to 0.8
against the rule's 0.3) and the default fitted them as a feedback loop.  Genuine loops run on the
same irregular clocks must still be recognised.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from identify import fit
from identify.default.feedback import FEEDBACK_SHARE, clock_deviation, feedback_evidence, feedback_share, sample_index
from motorsim import Encoder, Experiment, Motor, Recording, SimRig, Sine, Step
from motorsim.plant import simulate

A, B = 25.0, 3.0


def clock_driven(seed: int, waveform, *, h: float = 0.005, cpr: int = 16667, jitter: float = 0.05,
                 drop: float = 0.0, seq: bool = True, speed: bool = False, seconds: float = 4.0) -> Recording:
    """An open-loop run whose firmware computes ``waveform(t)`` (duty) at each sample's own instant ``t``: the
    instants ``k h + U(-jitter, jitter) h / 2``, the plant integrated exactly over the true intervals, each
    sample lost with probability ``drop`` (``seq`` kept, or left out of the file), counts or the firmware's
    speed (counts differenced over the measured interval)."""
    rng = np.random.default_rng(seed)
    n = int(round(seconds / h))
    t = np.arange(n) * h + rng.uniform(-0.5, 0.5, n) * jitter * h
    t -= t[0]
    duty = np.round(waveform(t))
    angle = simulate(Motor(A, B, friction=20.0), duty, t).angle
    counts = np.floor(angle * cpr / (2 * np.pi)).astype(np.int64)
    keep = np.ones(n, bool)
    keep[1:] = rng.random(n - 1) >= drop
    t, duty, counts = t[keep], duty[keep], counts[keep]
    index = np.arange(n)[keep] if seq else None
    if speed:
        rate = np.r_[0.0, np.diff(counts) * 2 * np.pi / cpr / np.diff(t)]
        return Recording(time=t, duty=duty, sample_period=h, speed=np.round(rate, 9), seq=index)
    return Recording(time=t, duty=duty, sample_period=h, counts=counts, counts_per_rev=cpr, seq=index)


def without_seq(rec: Recording) -> Recording:
    """The run as a file without ``seq`` (nor metadata, nor reference) reads: a lost sample shows in the time
    column only."""
    return Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, counts=rec.counts,
                     counts_per_rev=rec.counts_per_rev, speed=rec.speed)


def sine10(t):
    return 200 * np.sin(2 * np.pi * 10 * t)


def sine3(t):
    return 180 * np.sin(2 * np.pi * 3 * t + 0.5)


def multisine(t):
    return 80 * np.sin(2 * np.pi * 3 * t) + 60 * np.sin(2 * np.pi * 17 * t + 1) + 40 * np.sin(2 * np.pi * 70 * t + 2)


def chirp(t):
    return 200 * np.sin(2 * np.pi * (t + 5 * t ** 2))


def bench(seed: int, excitation, *, h: float, cpr: int, jitter: float, drop: float, speed: bool) -> Recording:
    """The simulated bench's own jitter and lost samples (its waveform set by the sample's number)."""
    rig = SimRig(Motor(A, B, friction=20.0), Encoder(cpr), jitter=jitter, drop_rate=drop, record_speed=speed,
                 rng=np.random.default_rng(seed))
    return rig.run(Experiment(excitation, h, 4.0))


# Open-loop runs on irregular clocks, with the share before the clock was taken out -> now (measured; the
# rule is 0.3: the first five were taken for loops)
OPEN_LOOP_IRREGULAR = {
    "clock sine, 5 ms, 16667 counts, jitter 5 %": lambda: clock_driven(1, sine10),                  # 0.64 -> 0.00
    "clock sine, 1 ms, jitter 20 %, 3 % lost, no seq": lambda: clock_driven(
        2, sine10, h=0.001, jitter=0.2, drop=0.03, seq=False),                                       # 0.77 -> 0.00
    "clock sine, 5 ms, 360 counts, jitter 5 %, 3 % lost, no seq": lambda: clock_driven(
        3, sine10, cpr=360, drop=0.03, seq=False),                                                    # 0.66 -> 0.00
    "clock 3 Hz sine, jitter 20 %": lambda: clock_driven(2, sine3, jitter=0.2),                     # 0.33 -> 0.00
    "clock 3 Hz sine, firmware's speed, jitter 20 %, 3 % lost, no seq": lambda: clock_driven(
        5, sine3, jitter=0.2, drop=0.03, seq=False, speed=True),                                      # 0.49 -> 0.01
    "clock chirp, 1 ms, jitter 20 %, 3 % lost": lambda: clock_driven(
        6, chirp, h=0.001, jitter=0.2, drop=0.03),                                                    # 0.24 -> 0.00
    "clock multisine, jitter 40 %": lambda: clock_driven(6, multisine, jitter=0.4),                 # 0.03 -> 0.02
    "bench sine, speed column, jitter 5 %, 3 % lost, no seq": lambda: without_seq(bench(
        310, Sine(10.0, 200), h=0.005, cpr=16667, jitter=0.05, drop=0.03, speed=True)),               # 0.24 -> 0.02
}


@pytest.mark.parametrize("name", OPEN_LOOP_IRREGULAR)
def test_irregular_timing_in_open_loop_is_not_a_loop(name):
    # the rule is FEEDBACK_SHARE (0.3); on these runs the share is now at most 0.02 (measured; 2 928 runs of a
    # wider survey: at most 0.14), so holding them to 0.1 shows a margin shrinking before the rule is reached
    rec = OPEN_LOOP_IRREGULAR[name]()
    share = feedback_share(rec)
    assert math.isfinite(share), "the test must have run, not given up"
    assert share < 0.1 < FEEDBACK_SHARE
    assert feedback_evidence(rec) == ""


def test_a_constant_duty_has_nothing_to_test():
    # the duty never changes (a step at the start) and 5 % of the samples are lost: the duty's innovation is the
    # arithmetic's rounding, whose "share" was anything (1.0 on this run: taken for a loop); no evidence now
    rec = bench(2, Step(), h=0.005, cpr=12, jitter=0.0, drop=0.05, speed=True)
    time = rec.time + np.random.default_rng(3).uniform(-0.05, 0.05, len(rec)) * rec.sample_period
    rec = Recording(time=time, duty=rec.duty, sample_period=rec.sample_period, speed=rec.speed, seq=rec.seq)
    assert np.ptp(rec.duty) == 0
    assert math.isnan(feedback_share(rec))
    assert feedback_evidence(rec) == ""


def _loop(seed: int, kind: str, *, h: float, jitter: float, drop: float, disturbance: float) -> Recording:
    from motorsim.control import ClosedLoopExperiment, OneStepMPC, PISpeed, PlantModel, PositionPD, Reference
    model = PlantModel(A, B, h, 2000)
    controller = {"pi": PISpeed(model, time_constant=0.05), "mpc": OneStepMPC(model),
                  "position": PositionPD(model, time_constant=0.05)}[kind]
    speed, angle = (2 * np.pi, 5.2 * np.pi), (np.pi, 2.6 * np.pi)
    reference = Reference("multisine", frequencies=angle if kind == "position" else speed,
                          amplitudes=(2.0, 1.0) if kind == "position" else (20.0, 10.0), phases=(0.0, 1.0))
    rig = SimRig(Motor(A, B, friction=20.0), Encoder(2000), jitter=jitter, drop_rate=drop, disturbance=disturbance,
                 disturbance_time=0.1, rng=np.random.default_rng(seed))
    return rig.run(ClosedLoopExperiment(controller, reference, 4.0))


@pytest.mark.parametrize("kind", ["pi", "mpc", "position"])
@pytest.mark.parametrize("h, jitter, drop, disturbance", [(0.001, 0.05, 0.0, 0.0), (0.005, 0.3, 0.05, 30.0),
                                                           (0.001, 0.3, 0.05, 0.0)])
def test_loops_on_irregular_clocks_are_still_recognised(kind, h, jitter, drop, disturbance):
    # the same clocks in closed loop, the file declaring nothing (no seq either): the duty answers the output
    # (measured 0.70 and more on these; 0.81 and more on regular clocks), far above the rule
    run = _loop(11, kind, h=h, jitter=jitter, drop=drop, disturbance=disturbance)
    assert "controller" in feedback_evidence(run)
    bare = without_seq(run)
    assert feedback_share(bare) > 0.5 > FEEDBACK_SHARE
    assert "explains" in feedback_evidence(bare)


def _still(time, seq=None) -> Recording:
    n = len(time)
    return Recording(time=time, duty=np.zeros(n), sample_period=0.01, seq=seq, counts=np.zeros(n, dtype=np.int64),
                     counts_per_rev=100)


def test_sample_index_counts_a_sample_the_time_column_shows_lost():
    t = np.array([0.0, 0.0104, 0.0197, 0.0402, 0.0498, 0.0801])    # two and three periods after rows 2 and 4
    assert sample_index(_still(t)).tolist() == [0, 1, 2, 4, 5, 8]
    # seq's own gap counts as it says, where the time column shows none
    assert sample_index(_still(np.arange(6) * 0.01, seq=[0, 1, 2, 7, 8, 9])).tolist() == [0, 1, 2, 7, 8, 9]


def test_a_clock_irregular_enough_to_stretch_an_interval_by_itself_leaves_seq_to_say():
    # intervals from 0.3 to 1.7 periods: a 1.6-period interval is no evidence of a lost sample
    t = np.cumsum([0.0, 1.0, 0.3, 1.7, 1.0, 1.6]) * 0.01
    assert sample_index(_still(t)).tolist() == [0, 1, 2, 3, 4, 5]


def test_clock_deviation_is_the_jitter_about_a_clock_of_its_own_rate():
    # a clock 0.1 % fast with an offset: its rate and offset are no deviation; the jitter is, to rounding
    rng = np.random.default_rng(0)
    k = np.arange(500)
    jitter = rng.uniform(-0.1, 0.1, 500)
    jitter -= np.polyval(np.polyfit(k, jitter, 1), k)                     # what a line cannot take out
    t = 0.3 + 1.001 * 0.002 * k + jitter * 0.002
    assert np.max(np.abs(clock_deviation(t, k, 0.002) - jitter)) < 1e-9


@pytest.mark.slow
def test_default_fits_a_jittered_open_loop_run_as_open_loop():
    # the user's view: `motorid identify FILE` with no flags on the firmware-clocked sine at 5 ms (share 0.72
    # before: pem-disturbance, called clear).  Now no closed-loop note, an output-error answer within 1 % whose
    # intervals hold the truth (measured: a -0.08 %, b +0.01 %; before: a -0.8 %)
    rec = clock_driven(1, sine10)
    est = fit(rec)
    assert est.method != "pem-disturbance"
    assert not any("closed loop" in note for note in est.notes)
    ci = est.confidence_interval(0.95)
    assert abs(est.a / A - 1) < 0.01 and abs(est.b / B - 1) < 0.01
    assert ci["a"][0] <= A <= ci["a"][1] and ci["b"][0] <= B <= ci["b"][1]
