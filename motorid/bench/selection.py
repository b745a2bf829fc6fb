"""``motorid bench selection``: what choosing the model by evidence costs, against one fit and a CSV read.

The goals (:mod:`motorid.bench.goals`), each a ratio of CPU times measured in alternation in one
run, or the CPU time of a user's file, and each over a small family of recordings, not one (a goal
met on one recording can miss on its neighbour): the figure is the family's worst.

* on 10 000 samples of a multisine read by an encoder with 1e-4 rad of noise, the default
  (``identify.fit(rec)``: input delay and structure chosen) within 10 times one ``oe`` fit at a
  fixed delay of the same recording, on the bench's own two recordings (5 ms, 16667 counts, with
  no friction and with Coulomb friction of 30 % of the largest drive ``b max|u|``), and within the
  limit of :data:`FIT_FAMILY_GOAL` over the whole :data:`FAMILY` (1-5 ms, 360-16667 counts,
  friction 0 and 5-40 % of the drive);
* one ``oe-friction`` fit at a fixed delay within 5 times one ``oe`` fit on the family's members
  without friction, and within the limit of :data:`OE_FRICTION_GOAL` on those with friction (3
  times on the bench's own friction recording, :data:`OE_FRICTION_OWN_GOAL`);
* 15 000-sample recordings made inside a position loop (a PD controller tracking slow sines
  through Coulomb friction and a random load torque, :func:`position_loop_recording`, three
  seeds): ``motorid identify FILE``'s work (read, screen, the default fit, the outlier check:
  :func:`motorid.screening.read_and_fit`) within 3 s;
* the same work within 3 s on 15 000-sample, 1 ms recordings of a PD position loop whose random
  torque the loop feeds back hard enough that the default fits by prediction error
  (:func:`torque_loop_recording`, three seeds: the delays and structures compared under feedback,
  the chosen fit refitted with the disturbance as a random walk);
* end to end on a 10^6-row recording file, the same work within 3 times ``pandas.read_csv`` of the
  same file, and the peak memory of a ``motorid identify FILE`` process within 2 times that of a
  process that imports pandas and reads the file.
"""
from __future__ import annotations

import argparse
import functools
import math
import sys
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np

from motorid.bench.flags import integer
from motorid.bench.goals import Goal, report
from motorid.bench.timing import cpu_clock, interleaved_rounds, least_time, median_ratio

__all__ = ["bench_selection", "goal_figures", "position_loop_recording", "torque_loop_recording", "fit_family",
           "peak_memory", "GOALS", "FAMILY", "FIT_GOAL", "FRICTION_FIT_GOAL", "FIT_FAMILY_GOAL", "OE_FRICTION_GOAL",
           "OE_FRICTION_OWN_GOAL", "OE_FRICTION_LINEAR_GOAL", "POSITION_LOOP_GOAL", "TORQUE_LOOP_GOAL", "FILE_GOAL",
           "FILE_MEMORY_GOAL"]

#: Open: measured 10.0-10.2 x in CPU time (gate runs and alternated processes beside other work, two of them busy
#: loops; 10.6-10.8 x before the candidates shared their first step); the gate holds it at 12 x meanwhile, so that it
#: runs in CI (``.ci/run``) and still fails a change that makes the default slower.
FIT_GOAL = Goal("default / one oe fit, 10^4-sample multisine (5 ms, 16667 counts)", 10.0, held=12.0)
FRICTION_FIT_GOAL = Goal("default / one oe fit, the same through 30 % Coulomb friction", 10.0)
FIT_FAMILY_GOAL = Goal("default / one oe fit, worst of the family (1-5 ms, 360-16667 counts, friction 0-40 %)",
                       40.0)
OE_FRICTION_LINEAR_GOAL = Goal("oe-friction / one oe fit, worst of the family without friction", 5.0)
OE_FRICTION_OWN_GOAL = Goal("oe-friction / one oe fit, 10^4-sample multisine, 30 % Coulomb friction", 3.0)
OE_FRICTION_GOAL = Goal("oe-friction / one oe fit, worst of the family with friction (5-40 %)", 8.0)
POSITION_LOOP_GOAL = Goal("identify FILE, 15 000-sample position loop with friction (worst of 3)", 3.0, "s")
TORQUE_LOOP_GOAL = Goal("identify FILE, 15 000-sample 1 ms position loop, fed-back torque (worst of 3)", 3.0, "s")
#: Open: 2.75-3.10 x in CPU time on a 2-core machine at load 10-21 (3.45-4.5 x before the reader read each file
#: once and its checks stopped partitioning and copying whole columns; 5.4 x, and 6.2-8.0 x before the fits ran BLAS
#: on one thread and the part checks took the fit's own model): about 3 x, not within it with a margin on a busy
#: machine, so the gate holds it at 3.5 x meanwhile.
FILE_GOAL = Goal("identify FILE / pandas.read_csv, 10^6 rows", 3.0, held=3.5)
FILE_MEMORY_GOAL = Goal("motorid identify FILE / pandas.read_csv, peak memory of the process, 10^6 rows", 2.0)
GOALS = (FIT_GOAL, FRICTION_FIT_GOAL, FIT_FAMILY_GOAL, OE_FRICTION_LINEAR_GOAL, OE_FRICTION_OWN_GOAL, OE_FRICTION_GOAL,
         POSITION_LOOP_GOAL, TORQUE_LOOP_GOAL, FILE_GOAL, FILE_MEMORY_GOAL)

#: Coulomb friction of the bench's own friction multisine, as a share of the largest drive ``b max|u|``.
FRICTION_SHARE = 0.3

#: The recordings every fit goal is measured on: (Coulomb friction as a share of the largest drive, sample period
#: in s, encoder counts per revolution).  The first is the bench's own multisine, the fourth its friction multisine.
FAMILY = ((0.0, 0.005, 16667), (0.0, 0.001, 1000), (0.0, 0.002, 360),
          (FRICTION_SHARE, 0.005, 16667), (0.05, 0.002, 16667), (0.4, 0.001, 1000), (0.15, 0.005, 360))

#: Seeds of the position-loop recordings each loop goal is measured on.
LOOP_SEEDS = (0, 1, 2)


def _multisine(samples: int, friction_share: float = 0.0, seed: int = 0, sample_period: float = 0.005,
               counts_per_rev: int = 16667):
    from motorsim import Encoder, Experiment, Motor, Multisine, SimRig
    excitation = Multisine((5.0, 17.0, 41.0, 90.0), (60, 60, 50, 40), (0, 1, 2, 3))
    dt = sample_period
    friction = friction_share * 3.0 * float(np.max(np.abs(excitation.duty(samples, dt))))
    rig = SimRig(Motor(25.0, 3.0, friction=friction), Encoder(counts_per_rev, angle_noise=1e-4),
                 rng=np.random.default_rng(seed))
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


def fit_family(samples: int = 10_000, repeats: int = 5, verbose: bool = False) -> list[tuple[float, float]]:
    """The default and one ``oe-friction`` fit over one ``oe`` fit on each recording of :data:`FAMILY`.

    Each pair of ratios is the median over ``repeats`` rounds of the three fits timed in
    alternation, in CPU time (the fits are single-threaded).  Returns ``[(default / oe,
    oe-friction / oe), ...]`` in the order of :data:`FAMILY`.
    """
    from identify import fit
    ratios = []
    for share, dt, cpr in FAMILY:
        rec = _multisine(samples, share, sample_period=dt, counts_per_rev=cpr)
        rounds = interleaved_rounds([functools.partial(fit, rec), functools.partial(fit, rec, "oe", input_delay=0),
                                     functools.partial(fit, rec, "oe-friction", input_delay=0)], repeats,
                                    clock=cpu_clock)
        ratios.append((median_ratio(rounds, 0, 1), median_ratio(rounds, 2, 1)))
        if verbose:
            t_default, t_oe, t_friction = np.median(rounds, axis=0)
            print(f"multisine, friction {100 * share:2g} %, {1e3 * dt:g} ms, {cpr:5d} counts: default "
                  f"{1e3 * t_default:7.1f} ms ({ratios[-1][0]:5.1f} x), one oe fit {1e3 * t_oe:6.2f} ms, one "
                  f"oe-friction fit {1e3 * t_friction:6.2f} ms ({ratios[-1][1]:4.1f} x)  [CPU]", flush=True)
    return ratios


def _fit_figures(samples: int, repeats: int, verbose: bool) -> list[tuple[Goal, float]]:
    """The fit goals from :func:`fit_family`: the bench's own two recordings and the family's worst."""
    ratios = fit_family(samples, repeats, verbose)
    own, friction = FAMILY.index((0.0, 0.005, 16667)), FAMILY.index((FRICTION_SHARE, 0.005, 16667))
    linear = [r for r, (share, _, _) in zip(ratios, FAMILY) if share == 0]
    rough = [r for r, (share, _, _) in zip(ratios, FAMILY) if share > 0]
    return [(FIT_GOAL, ratios[own][0]), (FRICTION_FIT_GOAL, ratios[friction][0]),
            (FIT_FAMILY_GOAL, max(r[0] for r in ratios)),
            (OE_FRICTION_LINEAR_GOAL, max(r[1] for r in linear)), (OE_FRICTION_OWN_GOAL, ratios[friction][1]),
            (OE_FRICTION_GOAL, max(r[1] for r in rough))]


def _identify_file(rec, repeats: int) -> float:
    """Least CPU seconds of ``identify FILE``'s work (:func:`motorid.screening.read_and_fit`) on ``rec`` written out."""
    from motorid.screening import read_and_fit
    from motorsim.writing import write_recording
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.csv"
        write_recording(rec, path)
        return least_time(lambda: read_and_fit([str(path)], "auto", {}), repeats)


def _loop_figures(samples: int, repeats: int, verbose: bool) -> list[tuple[Goal, float]]:
    """The worst over :data:`LOOP_SEEDS` of ``identify FILE`` on each kind of position-loop recording."""
    figures = []
    for goal, make, label in ((POSITION_LOOP_GOAL, position_loop_recording, "position loop"),
                              (TORQUE_LOOP_GOAL, torque_loop_recording, "position loop at 1 ms, fed-back torque")):
        seconds = [_identify_file(make(samples, seed), repeats) for seed in LOOP_SEEDS]
        if verbose:
            print(f"{label}, {samples} samples: identify FILE " + ", ".join(f"{s:5.2f}" for s in seconds)
                  + " s  [CPU, seeds " + ", ".join(map(str, LOOP_SEEDS)) + "]", flush=True)
        figures.append((goal, max(seconds)))
    return figures


#: The child of :func:`peak_memory`: reports its own peak resident memory at exit, then runs ``argv[1:]`` as
#: ``python -m MODULE ...`` (``-m``) or ``python -c CODE ...``.  Its own: a process's ``ru_maxrss`` on Linux
#: starts at its parent's resident size when it was forked, the high-water mark of ``/proc/self/status``
#: (``VmHWM``) is of its own program alone.
_MEASURED_CHILD = """
import atexit, resource, runpy, sys
def peak():
    try:
        with open("/proc/self/status") as f:
            kb = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    except (OSError, StopIteration):
        kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    sys.stderr.write(f"\\npeak-memory-kB {kb}\\n")
    sys.stderr.flush()
atexit.register(peak)
kind, target, *args = sys.argv[1:]
sys.argv = [target, *args]
if kind == "-m":
    runpy.run_module(target, run_name="__main__", alter_sys=True)
else:
    exec(compile(target, "<bench>", "exec"), {"__name__": "__main__"})
"""

#: What the baseline process runs: pandas imported, the file read.
_PANDAS_READ = "import sys, pandas; pandas.read_csv(sys.argv[1], comment='#')"


def peak_memory(kind: str, target: str, *args: str) -> float:
    """Peak resident memory in bytes of a new Python process running ``python KIND TARGET ARGS...``.

    ``kind`` is ``-m`` (``target`` a module, as ``python -m``) or ``-c`` (``target`` code); the
    process reports its own peak (:data:`_MEASURED_CHILD`).
    """
    import subprocess
    proc = subprocess.run([sys.executable, "-c", _MEASURED_CHILD, kind, target, *args], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True, check=False)
    lines = [line for line in proc.stderr.splitlines() if line.startswith("peak-memory-kB ")]
    if proc.returncode or not lines:
        raise RuntimeError(f"python {kind} {target} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return int(lines[-1].split()[1]) * 1024.0


def _file_figures(rows: int, repeats: int, verbose: bool) -> list[tuple[Goal, float]]:
    """``identify FILE`` against ``pandas.read_csv`` on ``rows`` rows: CPU time in alternation, and peak memory."""
    import pandas

    from motorid.screening import read_and_fit
    from motorsim.writing import write_recording
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long.csv"
        write_recording(_multisine(rows), path)
        rounds = interleaved_rounds([lambda: read_and_fit([str(path)], "auto", {}),
                                     lambda: pandas.read_csv(path, comment="#")], repeats, clock=cpu_clock)
        ours = min(peak_memory("-m", "motorid", "identify", str(path)) for _ in range(2))
        theirs = min(peak_memory("-c", _PANDAS_READ, str(path)) for _ in range(2))
    ratio = median_ratio(rounds, 0, 1)
    if verbose:
        t_ours, t_pandas = np.median(rounds, axis=0)
        print(f"{rows} rows: identify FILE {t_ours:6.3f} s, pandas.read_csv {t_pandas:6.3f} s ({ratio:4.2f} x) [CPU]; "
              f"peak memory: motorid identify {ours / 2**20:5.0f} MB, pandas {theirs / 2**20:5.0f} MB", flush=True)
    return [(FILE_GOAL, ratio), (FILE_MEMORY_GOAL, ours / theirs)]


def goal_figures() -> list[tuple[Goal, float]]:
    """Every goal of :data:`GOALS` at its size (``motorid bench --check``)."""
    return (_fit_figures(10_000, 5, verbose=False) + _loop_figures(15_000, 3, verbose=False)
            + _file_figures(10**6, 5, verbose=False))


def bench_selection(argv: Sequence[str]) -> int:
    """The default's fit time against one ``oe`` fit, position-loop files, ``identify FILE`` against pandas."""
    p = argparse.ArgumentParser(prog="motorid bench selection", description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=integer(), default=10_000, help="samples of the fit comparison (default 10000)")
    p.add_argument("--loop-samples", type=integer(0), default=15_000,
                   help="samples of the position-loop recordings (default 15000; 0 skips)")
    p.add_argument("--rows", type=integer(0), default=10**6,
                   help="rows of the file comparison (default 1000000; 0 skips)")
    p.add_argument("--repeats", type=integer(), default=5, help="timings to take the median of (default 5)")
    args = p.parse_args(list(argv))
    figures = _fit_figures(args.samples, args.repeats, verbose=True)
    if args.loop_samples:
        figures += _loop_figures(args.loop_samples, max(1, min(args.repeats, 3)), verbose=True)
    if args.rows:
        try:
            figures += _file_figures(args.rows, args.repeats, verbose=True)
        except ImportError:
            print("the file comparison needs pandas (pip install 'motorid[bench]')", file=sys.stderr)
            return 2
    # the goals hold at their sizes; other sizes print the figures against them for comparison
    at_size = args.samples == 10_000 and args.loop_samples in (0, 15_000) and args.rows in (0, 10**6)
    missed = report(figures)
    return missed if at_size else 0
