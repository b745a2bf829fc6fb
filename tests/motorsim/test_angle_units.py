"""An angle column in degrees read as radians is caught; a radian angle column never is (no false alarm).

The radian cases are the encoders of simulated runs across motors, resolutions, excitations and
sample periods, as a lab would write them: full precision, rounded to a few digits, behind a
gearbox (a counts per revolution that is no whole number), noisy, with a speed column; and the
real UNDCMotor run's speed integrated to an angle.
"""
from __future__ import annotations

import itertools
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from motorsim import Experiment, Motor, Recording, SimRig
from motorsim.excitation import parse_excitation
from motorsim.plausibility import MAX_SPEED, angle_unit_doubt
from motorsim.recording import AngleUnitWarning
from motorsim.sensors import Encoder

DATA = Path(__file__).resolve().parents[1] / "data" / "undcmotor"
MOTORS = [(2.0, 0.5), (25.0, 3.0), (90.0, 30.0), (5.0, 40.0)]
RESOLUTIONS = [44, 1000, 1024, 16667, 100000]
EXCITATIONS = ["sine:10,200,0", "prbs:200,-200,10", "step:150", "multisine:5,60,0;17,60,1;41,50,2"]


def _runs():
    for (a, b), cpr, spec in itertools.product(MOTORS, RESOLUTIONS, EXCITATIONS):
        rec = SimRig(Motor(a, b), Encoder(counts_per_rev=cpr), record_speed=True).run(
            Experiment(parse_excitation(spec), 0.005, 2.0))
        yield f"a={a:g} b={b:g} cpr={cpr} {spec}", rec, (rec.counts - rec.counts[0] + 1234).astype(float), cpr


RUNS = list(_runs())


def _radian_columns(counts: np.ndarray, cpr: int, speed: np.ndarray, rng: np.random.Generator):
    rad = counts * 2 * math.pi / cpr
    yield "full precision", rad, None
    for digits in (3, 6):
        yield f"{digits} digits", np.round(rad, digits), None
    for ratio in (3.7, 19.2, 34.014):
        yield f"gearbox {ratio}", rad / ratio, None
        yield f"gearbox {ratio}, 6 digits", np.round(rad / ratio, 6), None
    yield "with a speed column", rad, speed
    yield "noisy", rad + rng.normal(0.0, 1e-3, len(rad)), None


def test_no_radian_angle_column_of_a_simulated_run_is_doubted():
    rng = np.random.default_rng(0)
    doubted = []
    for name, rec, counts, cpr in RUNS:
        for how, angle, speed in _radian_columns(counts, cpr, rec.speed, rng):
            doubt = angle_unit_doubt(angle, rec.time, rec.seq, speed)
            if doubt is not None:
                doubted.append((name, how, doubt.reason))
    assert doubted == []


def test_most_degree_angle_columns_are_caught_and_every_catch_says_degrees():
    caught = {"full precision": 0, "with a speed column": 0}
    for _, rec, counts, cpr in RUNS:
        degrees = counts * 360 / cpr
        for how, speed in (("full precision", None), ("with a speed column", rec.speed)):
            doubt = angle_unit_doubt(degrees, rec.time, rec.seq, speed)
            if doubt is not None:
                assert doubt.unit == "deg", doubt
                caught[how] += 1
    # a miss (few positions visited, a motor too fast to step one count) is allowed; most are caught
    assert caught["full precision"] >= 0.5 * len(RUNS) and caught["with a speed column"] >= 0.8 * len(RUNS), caught


def test_counts_in_an_angle_column_are_called_counts():
    _, rec, counts, _ = RUNS[1]
    assert angle_unit_doubt(counts, rec.time, rec.seq).unit == "counts"


def test_a_speed_beyond_any_motor_reads_as_degrees():
    t = np.arange(2000) * 0.001
    angle = np.degrees(600.0 * t + 0.01 * np.sin(40 * t))     # 600 rad/s (5700 rpm), in degrees, not stepped
    doubt = angle_unit_doubt(angle, t, np.arange(2000))
    assert doubt is not None and doubt.unit == "deg" and f"{MAX_SPEED:g} rad/s" in doubt.reason
    assert angle_unit_doubt(np.radians(angle), t, np.arange(2000)) is None


@pytest.mark.parametrize("name", ["DCmotor_prbs_open_exp.csv", "DCmotor_step_open_exp.csv"])
def test_the_real_runs_angle_is_doubted_only_in_degrees(name):
    """UNDCMotor gives speed in deg/s; its integral is an angle, in radians or (wrongly read) degrees."""
    t, _, speed_deg = np.loadtxt(DATA / name, delimiter=",", skiprows=1, unpack=True)
    seq = np.arange(len(t))
    angle_deg = np.concatenate([[0.0], np.cumsum((speed_deg[1:] + speed_deg[:-1]) / 2 * np.diff(t))])
    assert angle_unit_doubt(np.radians(angle_deg), t, seq, np.radians(speed_deg)) is None
    assert angle_unit_doubt(np.radians(angle_deg), t, seq) is None
    doubt = angle_unit_doubt(angle_deg, t, seq, np.radians(speed_deg))
    assert doubt is not None and doubt.unit == "deg" and "57.3 times as fast as the speed column" in doubt.reason


def test_from_columns_warns_about_an_angle_said_to_be_radians_that_reads_as_degrees():
    _, rec, counts, cpr = next(run for run in RUNS if run[0] == "a=25 b=3 cpr=16667 sine:10,200,0")
    with pytest.warns(AngleUnitWarning, match="angle_unit='deg'"):
        Recording.from_columns(time=rec.time, duty=rec.duty, angle=counts * 360 / cpr)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Recording.from_columns(time=rec.time, duty=rec.duty, angle=counts * 360 / cpr, angle_unit="deg")
        Recording.from_columns(time=rec.time, duty=rec.duty, angle=counts * 2 * math.pi / cpr)
