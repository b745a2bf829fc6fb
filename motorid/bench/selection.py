"""``motorid bench selection``: what choosing the model by evidence costs, against one fit and a CSV read.

The goals (:mod:`motorid.bench.goals`), each a ratio measured in one run or a time on a user's file:

* on 10 000 samples of a multisine on a 16667-count encoder, the default (``identify.fit(rec)``:
  input delay and structure chosen) within 10 times one ``oe`` fit at a fixed delay of the same
  recording, for the linear motor the default meets most and for the same multisine through
  Coulomb friction of 30 % of the largest drive ``b max|u|`` (friction is the rule on real rigs);
* on the same two recordings, one ``oe-friction`` fit at a fixed delay within 3 times one ``oe``
  fit through friction and within 5 times without;
* a 15 000-sample recording made inside a position loop (a PD controller tracking slow sines
  through Coulomb friction and a random load torque, :func:`position_loop_recording`): ``motorid
  identify FILE``'s work (read, screen, the default fit, the outlier check:
  :func:`motorid.screening.read_and_fit`) within 3 s;
* the same work within 3 s on a 15 000-sample, 1 ms recording of a PD position loop whose random
  torque the loop feeds back hard enough that the default fits by prediction error
  (:func:`torque_loop_recording`: the delays and structures compared under feedback, the chosen
  fit refitted with the disturbance as a random walk);
* end to end on a 10^6-row recording file, the same work within 4 times ``pandas.read_csv`` of the
  same file.
"""
from __future__ import annotations

import argparse
import functools
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from motorid.bench.flags import integer
from motorid.bench.goals import Goal, report
from motorid.bench.timing import interleaved_times

__all__ = ["bench_selection", "goal_figures", "position_loop_recording", "torque_loop_recording", "GOALS", "FIT_GOAL",
           "FRICTION_FIT_GOAL", "OE_FRICTION_GOAL", "OE_FRICTION_LINEAR_GOAL", "POSITION_LOOP_GOAL",
           "TORQUE_LOOP_GOAL", "FILE_GOAL"]

FIT_GOAL = Goal("default / one oe fit, 10^4-sample multisine", 10.0)
FRICTION_FIT_GOAL = Goal("default / one oe fit, 10^4-sample multisine, 30 % Coulomb friction", 10.0)
OE_FRICTION_LINEAR_GOAL = Goal("oe-friction / one oe fit, 10^4-sample multisine", 5.0)
OE_FRICTION_GOAL = Goal("oe-friction / one oe fit, 10^4-sample multisine, 30 % Coulomb friction", 3.0)
POSITION_LOOP_GOAL = Goal("identify FILE, 15 000-sample position loop with friction", 3.0, "s")
TORQUE_LOOP_GOAL = Goal("identify FILE, 15 000-sample 1 ms position loop, fed-back torque", 3.0, "s")
FILE_GOAL = Goal("identify FILE / pandas.read_csv, 10^6 rows", 4.0)
GOALS = (FIT_GOAL, OE_FRICTION_LINEAR_GOAL, FRICTION_FIT_GOAL, OE_FRICTION_GOAL, POSITION_LOOP_GOAL, TORQUE_LOOP_GOAL,
         FILE_GOAL)

#: Coulomb friction of the friction multisine, as a share of the largest drive ``b max|u|``.
FRICTION_SHARE = 0.3


def _multisine(samples: int, friction_share: float = 0.0, seed: int = 0):
    from motorsim import Encoder, Experiment, Motor, Multisine, SimRig
    excitation = Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3))
    dt = 0.005
    friction = friction_share * 3.0 * float(np.max(np.abs(excitation.duty(samples, dt))))
    rig = SimRig(Motor(25.0, 3.0, friction=friction), Encoder(angle_noise=1e-4), rng=np.random.default_rng(seed))
    return rig.run(Experiment(excitation, dt, samples * dt))


def position_loop_recording(samples: int = 15_000, seed: int = 0):
    """A PD position loop tracking slow sines through Coulomb friction and a random load torque.

    The motor ``a = 25``, ``b = 3``, Coulomb friction 60 rad/s^2, a 16667-count encoder with 1e-4 rad
    of noise, 5 ms samples; :class:`motorsim.control.PositionPD` (time constant 0.1 s) tracks sines of
    12 and 5 rad at 1.1 and 2.9 rad/s; the load adds a torque that takes a new normal level (10 rad/s^2
    standard deviation) every 0.1 s.  The loop is the controller's integer step and the exact friction
    interval of :func:`motorsim.compiled.friction_interval`, sample by sample.
    """
    from motorsim.compiled import friction_interval
    from motorsim.control import ClosedLoopExperiment, PlantModel, PositionPD, Reference
    from motorsim.recording import Recording
    a, b, c, dt, cpr = 25.0, 3.0, 60.0, 0.005, 16667
    rng = np.random.default_rng(seed)
    controller = PositionPD(PlantModel(a, b, dt, cpr), time_constant=0.1)
    reference = Reference("multisine", frequencies=(1.1, 2.9), amplitudes=(12.0, 5.0), phases=(0.0, 1.0))
    experiment = ClosedLoopExperiment(controller, reference, samples * dt)
    loop = controller.start(experiment.reference_samples(), experiment.duty_limit)
    load = np.repeat(rng.normal(0.0, 10.0, samples // 20 + 1), 20)[:samples]
    noise = rng.normal(0.0, 1e-4, samples)
    scale = cpr / (2 * math.pi)
    duty = np.zeros(samples, dtype=np.int64)
    counts = np.zeros(samples, dtype=np.int64)
    w = th = 0.0
    for k in range(samples):
        counts[k] = math.floor((th + noise[k]) * scale)
        duty[k] = u = loop.step(k, int(counts[k]))
        w, th = friction_interval(a, b * u + load[k], c, w, th, dt, c)
    return Recording(time=np.arange(samples) * dt, duty=duty, sample_period=dt, counts=counts, counts_per_rev=cpr,
                     seq=np.arange(samples), metadata={"source": "motorid bench selection (position loop)"})


def torque_loop_recording(samples: int = 15_000, seed: int = 0):
    """A PD position loop tracking two slow sines through Coulomb friction and a random torque it feeds back.

    The motor ``a = 25``, ``b = 3``, Coulomb friction 60 rad/s^2, a 2000-count encoder, 1 ms samples;
    :class:`motorsim.control.PositionPD` (time constant 0.05 s) tracks sines of 2 and 1 rad at 0.5 and
    1.3 Hz; the simulated bench adds a random torque of 30 rad/s^2 RMS with a correlation time of 0.1 s
    (:class:`motorsim.SimRig`'s ``disturbance``), which the loop feeds back into the duty.
    """
    from motorsim import Encoder, Motor, SimRig
    from motorsim.control import ClosedLoopExperiment, PlantModel, PositionPD, Reference
    a, b, dt, cpr = 25.0, 3.0, 0.001, 2000
    controller = PositionPD(PlantModel(a, b, dt, cpr), time_constant=0.05)
    reference = Reference("multisine", frequencies=(np.pi, 2.6 * np.pi), amplitudes=(2.0, 1.0), phases=(0.0, 1.0))
    rig = SimRig(Motor(a, b, friction=60.0), Encoder(cpr), disturbance=30.0, disturbance_time=0.1,
                 rng=np.random.default_rng(seed))
    return rig.run(ClosedLoopExperiment(controller, reference, samples * dt))


def _fits(samples: int, repeats: int, verbose: bool) -> list[tuple[Goal, float]]:
    """The default and one ``oe-friction`` fit against one ``oe`` fit, with and without friction."""
    from identify import fit
    figures = []
    for label, share, goals in (("multisine", 0.0, (FIT_GOAL, OE_FRICTION_LINEAR_GOAL)),
                                (f"multisine, friction {100 * FRICTION_SHARE:g} %", FRICTION_SHARE,
                                 (FRICTION_FIT_GOAL, OE_FRICTION_GOAL))):
        rec = _multisine(samples, share)
        default = fit(rec)
        chosen = default.selection.chosen.label if default.selection else "no selection"
        t_default, t_oe, t_friction = interleaved_times(
            [functools.partial(fit, rec), functools.partial(fit, rec, "oe", input_delay=0),
             functools.partial(fit, rec, "oe-friction", input_delay=0)], repeats)
        figures += [(goals[0], t_default / t_oe), (goals[1], t_friction / t_oe)]
        if verbose:
            print(f"{label:28s} {samples} samples: default {1e3 * t_default:7.1f} ms ({chosen}), "
                  f"one oe fit {1e3 * t_oe:6.2f} ms, one oe-friction fit "
                  f"{1e3 * t_friction:6.2f} ms")
    return figures


def _identify_file(rec, repeats: int) -> float:
    """Median seconds of ``identify FILE``'s work (:func:`motorid.screening.read_and_fit`) on ``rec`` written out."""
    from motorid.screening import read_and_fit
    from motorsim.writing import write_recording
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.csv"
        write_recording(rec, path)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            read_and_fit([str(path)], "auto", {})
            times.append(time.perf_counter() - t0)
    return float(np.median(times))


def _file_ratio(rows: int, repeats: int) -> float:
    import pandas

    from motorid.screening import read_and_fit
    from motorsim.writing import write_recording
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long.csv"
        write_recording(_multisine(rows), path)
        t_identify, t_pandas = interleaved_times([lambda: read_and_fit([str(path)], "auto", {}),
                                                  lambda: pandas.read_csv(path, comment="#")], repeats)
    return t_identify / t_pandas


def goal_figures() -> list[tuple[Goal, float]]:
    """Every goal of :data:`GOALS` at its size (``motorid bench --check``)."""
    figures = _fits(10_000, 9, verbose=False)      # more rounds than the printout's: a steadier median
    figures.append((POSITION_LOOP_GOAL, _identify_file(position_loop_recording(), 3)))
    figures.append((TORQUE_LOOP_GOAL, _identify_file(torque_loop_recording(), 3)))
    figures.append((FILE_GOAL, _file_ratio(10**6, 3)))
    return figures


def bench_selection(argv: Sequence[str]) -> int:
    """The default's fit time against one ``oe`` fit, a position-loop file, ``identify FILE`` against pandas."""
    p = argparse.ArgumentParser(prog="motorid bench selection", description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=integer(), default=10_000, help="samples of the fit comparison (default 10000)")
    p.add_argument("--loop-samples", type=integer(0), default=15_000,
                   help="samples of the position-loop recordings (default 15000; 0 skips)")
    p.add_argument("--rows", type=integer(0), default=10**6,
                   help="rows of the file comparison (default 1000000; 0 skips)")
    p.add_argument("--repeats", type=integer(), default=5, help="timings to take the median of (default 5)")
    args = p.parse_args(list(argv))
    figures = _fits(args.samples, args.repeats, verbose=True)
    if args.loop_samples:
        seconds = _identify_file(position_loop_recording(args.loop_samples), max(1, min(args.repeats, 3)))
        print(f"position loop, {args.loop_samples} samples: identify FILE {seconds:6.2f} s")
        figures.append((POSITION_LOOP_GOAL, seconds))
        seconds = _identify_file(torque_loop_recording(args.loop_samples), max(1, min(args.repeats, 3)))
        print(f"position loop at 1 ms, fed-back torque, {args.loop_samples} samples: identify FILE {seconds:6.2f} s")
        figures.append((TORQUE_LOOP_GOAL, seconds))
    if args.rows:
        try:
            ratio = _file_ratio(args.rows, args.repeats)
        except ImportError:
            print("the file comparison needs pandas (pip install 'motorid[bench]')", file=sys.stderr)
            return 2
        figures.append((FILE_GOAL, ratio))
    # the goals hold at their sizes; other sizes print the figures against them for comparison
    at_size = args.samples == 10_000 and args.loop_samples in (0, 15_000) and args.rows in (0, 10**6)
    missed = report(figures)
    return missed if at_size else 0
