"""``motorid bench control``: closed-loop runs of the simulated bench against the open-loop run."""
from __future__ import annotations

import argparse
from functools import partial
from typing import Sequence

from motorid.bench.flags import integer, real
from motorid.bench.timing import median_time

__all__ = ["bench_control"]


def bench_control(argv: Sequence[str]) -> int:
    """Samples/s of ``SimRig.run`` in closed loop (each controller) vs open loop, same length."""
    from motorsim import Experiment, Motor, SimRig, Sine
    from motorsim.control import ClosedLoopExperiment, PlantModel, design_controller, parse_reference
    p = argparse.ArgumentParser(prog="motorid bench control", description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=real(), default=20.0, help="run length in s at 5 ms (default 20)")
    p.add_argument("--repeats", type=integer(), default=3, help="timings to take the median of (default 3)")
    args = p.parse_args(list(argv))
    dt = 0.005
    rig = SimRig(Motor(25.0, 3.0))
    model = PlantModel(25.0, 3.0, dt, 16667)
    n = int(round(args.duration / dt))
    t_open = median_time(lambda: rig.run(Experiment(Sine(10.0), dt, args.duration)), args.repeats)
    print(f"samples per run                 {n}  ({1 / dt:g} samples/s in real time)")
    print(f"{'open loop (sine excitation)':<31} {n / t_open / 1e3:9.1f} k samples/s")
    for kind, spec in (("mpc", "sine:10,10"), ("pi", "sine:10,10"), ("position", "sine:5,1"),
                       ("feedforward", "sine:10,10")):
        exp = ClosedLoopExperiment(design_controller(kind, model), parse_reference(spec), args.duration)
        t = median_time(partial(rig.run, exp), args.repeats)
        print(f"{'closed loop ' + kind:<31} {n / t / 1e3:9.1f} k samples/s  "
              f"{t / t_open:6.1f} x the open-loop time, {n * dt / t:7.0f} x real time")
    return 0
