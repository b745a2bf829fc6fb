"""``motorid bench coverage``: how often the default's intervals hold the truth of plants known exactly.

For each class of plant outside (and at the edge of) the first-order family — a driver's
electrical lag (behind a delay, under one sine), a delay past ten samples (with friction), a speed column
that differences encoder counts, Coulomb friction, a position or a speed loop that feeds a random torque
back — the default (``identify.fit`` with no
method) runs on ``--seeds`` recordings of independent noise, and the benchmark prints, per class,
how often the 95 % intervals of ``a`` and ``b`` hold the truth (goal: at least 90 %), how often
the answer is within 1 % of it, and the same coverage among the runs whose choice was called clear
(goal: at least 90 % too: "clear" is said only where the intervals cover; a 95 % interval misses
about one run in twenty by design, so no single run can promise more).  Exits 1 when a goal is
missed.

The classes marked ``past`` are plants one step past every registered structure
(:mod:`motorid.bench.misfits`: a current limit, a load switched on, a clipped duty, friction that weakens with
speed, asymmetric gains, a warming motor, an edge-timed speed column, backlash, cogging, gravity): no
structure fits them, so their only goal is the second — an answer called clear holds the truth (where
``a`` or ``b`` drifts or differs by direction, the whole range it spans) in at least 90 % of the runs.

Slow by design: one default fit per seed and class (a second to a minute each), run on
``--workers`` processes, the progress on stderr.

A class is one entry of :data:`CLASSES`: its name and a function ``(seed) -> Recording`` of a
plant whose ``a`` and ``b`` are :data:`A` and :data:`B`.
"""
from __future__ import annotations

import argparse
import functools
import sys
import time
from typing import Callable, NamedTuple, Sequence

import numpy as np

from motorid.bench.flags import integer
from motorid.bench.loop_misfits import LOOP_MISFITS, LOOP_TRUTH
from motorid.bench.misfits import MISFITS, random_rig
from motorid.bench.misfits import TRUTH as MISFIT_TRUTH

__all__ = ["bench_coverage", "CLASSES", "TRUTH", "COVERAGE_GOAL", "A", "B", "Outcome", "coverage_run"]

#: Share of runs whose 95 % intervals must hold the truth.
COVERAGE_GOAL = 0.90
#: The truth of every class: ``a`` in 1/s, ``b`` in (rad/s^2)/duty.
A, B = 25.0, 3.0


def _multisine():
    from motorsim import Multisine
    return Multisine((3.0, 17.0, 70.0, 200.0), (60, 50, 40, 40), (0, 1, 2, 3))


def _lag(time_constant: float, seed: int, input_delay: int = 0, sine: bool = False):
    """A driver whose current lags by ``time_constant`` s behind ``input_delay`` samples, multisine (or one sine
    of 20 rad/s), 1 ms, a fine encoder."""
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rig = SimRig(Motor(A, B, electrical_time_constant=time_constant, input_delay=input_delay),
                 Encoder(angle_noise=1e-4), rng=np.random.default_rng(seed))
    return rig.run(Experiment(Sine(20.0, 200) if sine else _multisine(), 0.001, 6.0))


def _delay(samples: int, seed: int, friction: float = 0.0):
    """An input delay of ``samples`` samples at 1 ms (a host-side loop), Coulomb friction ``friction``
    rad/s^2, multisine, a fine encoder."""
    from motorsim import Encoder, Experiment, Motor, SimRig
    rig = SimRig(Motor(A, B, input_delay=samples, friction=friction), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(seed))
    return rig.run(Experiment(_multisine(), 0.001, 6.0))


def _differenced(counts_per_rev: int, sample_period: float, seed: int):
    """A speed column only: the backward difference of ``counts_per_rev`` counts, rounded to 9 digits; the
    multisine's phases drawn from the seed (with no sensor noise they are what makes two seeds two runs)."""
    from motorsim import Encoder, Experiment, Motor, Multisine, Recording, SimRig
    rng = np.random.default_rng(seed)
    rig = SimRig(Motor(A, B), Encoder(counts_per_rev), rng=rng)
    phases = tuple(float(p) for p in rng.uniform(0.0, 2 * np.pi, 4))
    excitation = Multisine((2.0, 7.0, 23.0, 60.0), (60, 60, 50, 40), phases)
    rec = rig.run(Experiment(excitation, sample_period, 10.0))
    speed = rec.measured_speed()
    speed[0] = 0.0
    return Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, speed=np.round(speed, 9))


def _friction(seed: int):
    """Coulomb friction of 60 rad/s^2, one sine, 1000 counts at 5 ms."""
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rig = SimRig(Motor(A, B, friction=60.0), Encoder(1000, angle_noise=1e-4), rng=np.random.default_rng(seed))
    return rig.run(Experiment(Sine(10.0, 200), 0.005, 6.0))


def _stiction(ratio: float, seed: int):
    """Coulomb friction of 60 rad/s^2 whose break-away level is ``ratio`` times it, one sine, 1000 counts at 5 ms,
    the encoder's phase drawn from the seed."""
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rig = SimRig(Motor(A, B, friction=60.0, static_friction=ratio * 60.0),
                 Encoder(1000, angle_noise=1e-4, count_offset=seed % 1000), rng=np.random.default_rng(seed))
    return rig.run(Experiment(Sine(5.0, 200), 0.005, 6.0))


def _position_loop(seed: int):
    """A PD position loop tracking two slow sines, Coulomb friction of 60 rad/s^2 and a random
    torque of 30 rad/s^2 RMS (correlation time 0.1 s) that the loop feeds back; 2000 counts, 1 ms,
    15 s (:func:`motorid.bench.selection.torque_loop_recording`)."""
    from motorid.bench.selection import torque_loop_recording
    return torque_loop_recording(15_000, seed)


def _speed_loop(seed: int):
    """A PI speed loop tracking two sines (20 and 10 rad/s), Coulomb friction of 60 rad/s^2 and a random torque of
    30 rad/s^2 RMS (correlation time 0.1 s) that the loop feeds back; 2000 counts, 1 ms, 15 s."""
    from motorsim import Encoder, Motor, SimRig
    from motorsim.control import ClosedLoopExperiment, PISpeed, PlantModel, Reference
    controller = PISpeed(PlantModel(A, B, 0.001, 2000), time_constant=0.05)
    reference = Reference("multisine", frequencies=(2 * np.pi, 5.2 * np.pi), amplitudes=(20.0, 10.0), phases=(0.0, 1.0))
    rig = SimRig(Motor(A, B, friction=60.0), Encoder(2000), disturbance=30.0, disturbance_time=0.1,
                 rng=np.random.default_rng(seed))
    return rig.run(ClosedLoopExperiment(controller, reference, 15.0))


#: class name -> recording maker ``(seed) -> Recording`` (the truth is a = A, b = B unless :data:`TRUTH` says
#: otherwise), or ``(seed) -> (Recording, truth)`` where each seed's plant has its own (``random_rig``).  A new
#: class is one line here.
CLASSES: dict[str, Callable[[int], object]] = {
    "electrical lag 2 ms at 1 ms": functools.partial(_lag, 0.002),
    "electrical lag 4 ms at 1 ms": functools.partial(_lag, 0.004),
    "electrical lag 8 ms at 1 ms": functools.partial(_lag, 0.008),
    "electrical lag 10 ms, delay 3, at 1 ms": functools.partial(_lag, 0.01, input_delay=3),
    "electrical lag 3 ms, one sine, at 1 ms": functools.partial(_lag, 0.003, sine=True),
    "delay 13 samples at 1 ms": functools.partial(_delay, 13),
    "delay 14 samples at 1 ms": functools.partial(_delay, 14),
    "delay 20 samples at 1 ms": functools.partial(_delay, 20),
    "delay 15 samples, Coulomb friction": functools.partial(_delay, 15, friction=60.0),
    "differenced speed, 360 counts, 5 ms": functools.partial(_differenced, 360, 0.005),
    "differenced speed, 1000 counts, 2 ms": functools.partial(_differenced, 1000, 0.002),
    "Coulomb friction": _friction,
    "static friction 1.6 x sliding": functools.partial(_stiction, 1.6),
    "static friction 2 x sliding": functools.partial(_stiction, 2.0),
    "PD position loop, friction, torque": _position_loop,
    "PI speed loop, friction, torque": _speed_loop,
    **{f"past: {name}": maker for name, maker in MISFITS.items()},
    "past: random rigs": random_rig,
    **{f"past: {name}": maker for name, maker in LOOP_MISFITS.items()},
}
#: class name -> the range of ``a`` and of ``b`` an interval must hold (classes not listed: ``A`` and ``B``).
TRUTH = {f"past: {name}": truth for name, truth in {**MISFIT_TRUTH, **LOOP_TRUTH}.items()}


class Outcome(NamedTuple):
    """One default fit of one class and seed, against the truth."""

    covered: bool    #: both 95 % intervals hold the truth
    close: bool      #: a and b within 1 % of the truth
    clear: bool      #: the choice was called clear
    seconds: float   #: the fit's time
    refused: bool = False   #: the default refused the recording (no answer: neither covered nor clear)


def coverage_run(name: str, seed: int) -> Outcome:
    """The default fit on class ``name``'s recording of ``seed``, against the truth."""
    import warnings

    from identify import fit
    made = CLASSES[name](seed)
    rec, truth = made if isinstance(made, tuple) else (made, TRUTH.get(name, ((A, A), (B, B))))
    start = time.perf_counter()
    from identify.errors import CorruptedSamplesError, NotIdentifiableError
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            est = fit(rec)
        except (NotIdentifiableError, CorruptedSamplesError):
            # a refusal is an outcome of the default, counted: no answer, so neither covered nor clear
            return Outcome(False, False, False, time.perf_counter() - start, refused=True)
    seconds = time.perf_counter() - start
    ci = est.confidence_interval(0.95)
    (a_low, a_high), (b_low, b_high) = truth
    covered = bool(ci["a"][0] <= a_low and a_high <= ci["a"][1] and ci["b"][0] <= b_low and b_high <= ci["b"][1])
    close = bool(_off(est.a, a_low, a_high) <= 0.01 and _off(est.b, b_low, b_high) <= 0.01)
    return Outcome(covered, close, bool(est.selection and est.selection.clear), seconds)


def _off(x: float, low: float, high: float) -> float:
    """Relative distance of ``x`` from the range ``[low, high]`` (0 inside)."""
    return max(low - x, x - high, 0.0) / max(abs(low), abs(high))


def _row(name: str, outcomes: list[Outcome]) -> tuple[str, bool]:
    """The table row of one class and whether it meets both goals."""
    n = len(outcomes)
    covered = sum(o.covered for o in outcomes)
    clear = [o for o in outcomes if o.clear]
    clear_share = sum(o.covered for o in clear) / len(clear) if clear else 1.0
    met = (name.startswith("past: ") or covered / n >= COVERAGE_GOAL) and clear_share >= COVERAGE_GOAL
    mean_s = sum(o.seconds for o in outcomes) / n
    refused = sum(o.refused for o in outcomes)
    return (f"{name:44s} {n:5d} {100 * covered / n:7.0f} % {100 * sum(o.close for o in outcomes) / n:9.0f} % "
            f"{len(clear):6d} {100 * clear_share:14.0f} % {mean_s:7.1f}   {'met' if met else 'MISSED'}"
            + (f" ({refused} refused)" if refused else "")), met


def _progress(name: str, done: int, total: int) -> None:
    """``class: done/total`` on stderr: in place on a terminal, else a line every tenth of the class."""
    if sys.stderr.isatty():
        end = "\n" if done == total else ""
        print(f"\r{name}: {done}/{total}", end=end, file=sys.stderr, flush=True)
    elif done % max(1, total // 10) == 0 or done == total:
        print(f"{name}: {done}/{total}", file=sys.stderr, flush=True)


def bench_coverage(argv: Sequence[str]) -> int:
    """Run the benchmark (module docstring); 0 when every goal holds."""
    from scenarios.executors import points_executor, results_in_order
    if "--until" in argv:       # the adaptive runs' coverage under their stopping rule
        from motorid.bench.until import bench_until_coverage
        return bench_until_coverage([a for a in argv if a != "--until"])
    p = argparse.ArgumentParser(prog="motorid bench coverage", description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=integer(), default=100, help="recordings per class (default 100)")
    p.add_argument("--only", choices=list(CLASSES), action="append",
                   help="this class only (repeat for several; default every class)")
    p.add_argument("--workers", type=integer(), default=None, metavar="N",
                   help="worker processes (default: every core available)")
    p.add_argument("--until", action="store_true",
                   help="instead: motorid live --until's adaptive runs to ±1 %% on --seeds rigs (a 2...150 1/s, "
                        "friction, delay, lag) and how often their 95 %% intervals hold the built a and b "
                        "(motorid bench until; --target PCT)")
    args = p.parse_args(list(argv))
    names = [n for n in CLASSES if not args.only or n in args.only]
    jobs = [(name, seed) for name in names for seed in range(args.seeds)]
    print(f"{'class':44s} {'runs':>5s} {'covered':>8s} {'within 1 %':>10s} {'clear':>6s} {'clear, covered':>15s} "
          f"{'fit s':>7s}   goal >= {100 * COVERAGE_GOAL:.0f} % both", flush=True)
    ok, outcomes, start = True, [], time.perf_counter()
    with points_executor(args.workers, None) as (executor, window):
        for i, outcome in enumerate(results_in_order(executor, coverage_run, jobs, window)):
            outcomes.append(outcome)
            name = jobs[i][0]
            _progress(name, len(outcomes), args.seeds)
            if len(outcomes) == args.seeds:
                row, met = _row(name, outcomes)
                print(row, flush=True)
                ok &= met
                outcomes = []
    print(f"{len(jobs)} fits in {time.perf_counter() - start:.0f} s")
    return 0 if ok else 1
