"""``motorid bench coverage``: how often the default's intervals hold the truth of plants known exactly.

For each class of plant outside (and at the edge of) the first-order family — a driver's
electrical lag, a delay past ten samples, a speed column that differences encoder counts, Coulomb
friction — the default (``identify.fit`` with no method) runs on ``--seeds`` recordings of
independent noise, and the benchmark prints, per class, how often the 95 % intervals of ``a`` and
``b`` hold the truth (goal: at least 90 %), how often the answer is within 1 % of it, and the
same coverage among the runs whose choice was called clear (goal: at least 90 % too: "clear" is
said only where the intervals cover; a 95 % interval misses about one run in twenty by design, so
no single run can promise more).  Exits 1 when a goal is missed.  Slow by design: one default fit
per seed and class, about a second each.
"""
from __future__ import annotations

import argparse
from typing import Callable, Sequence

import numpy as np

from motorid.bench.flags import integer

__all__ = ["bench_coverage", "CLASSES", "COVERAGE_GOAL"]

#: Share of runs whose 95 % intervals must hold the truth.
COVERAGE_GOAL = 0.90
A, B = 25.0, 3.0


def _multisine():
    from motorsim import Multisine
    return Multisine((3.0, 17.0, 70.0, 200.0), (60, 50, 40, 40), (0, 1, 2, 3))


def _lag(seed: int):
    from motorsim import Encoder, Experiment, Motor, SimRig
    rig = SimRig(Motor(A, B, electrical_time_constant=0.004), Encoder(angle_noise=1e-4),
                 rng=np.random.default_rng(seed))
    return rig.run(Experiment(_multisine(), 0.001, 6.0))


def _delay(seed: int):
    from motorsim import Encoder, Experiment, Motor, SimRig
    rig = SimRig(Motor(A, B, input_delay=14), Encoder(angle_noise=1e-4), rng=np.random.default_rng(seed))
    return rig.run(Experiment(_multisine(), 0.001, 6.0))


def _differenced(seed: int):
    from motorsim import Encoder, Experiment, Motor, Multisine, Recording, SimRig
    rig = SimRig(Motor(A, B), Encoder(360, count_offset=int(seed) % 360), rng=np.random.default_rng(seed))
    excitation = Multisine((2.0, 7.0, 23.0, 60.0), (60, 60, 50, 40), (0, 1, 2, seed % 7))
    rec = rig.run(Experiment(excitation, 0.005, 10.0))
    speed = rec.measured_speed()
    speed[0] = 0.0
    return Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, speed=np.round(speed, 9))


def _friction(seed: int):
    from motorsim import Encoder, Experiment, Motor, SimRig, Sine
    rig = SimRig(Motor(A, B, friction=60.0), Encoder(1000, angle_noise=1e-4), rng=np.random.default_rng(seed))
    return rig.run(Experiment(Sine(10.0, 200), 0.005, 6.0))


#: class name -> recording maker ``(seed) -> Recording`` (the truth is a = 25, b = 3 throughout)
CLASSES: dict[str, Callable[[int], object]] = {
    "electrical lag 4 ms at 1 ms": _lag, "delay 14 samples at 1 ms": _delay,
    "differenced speed, 360 counts": _differenced, "Coulomb friction": _friction,
}


def bench_coverage(argv: Sequence[str]) -> int:
    """Run the benchmark (module docstring); 0 when every goal holds."""
    import warnings

    from identify import fit
    p = argparse.ArgumentParser(prog="motorid bench coverage", description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=integer(), default=100, help="recordings per class (default 100)")
    p.add_argument("--only", choices=list(CLASSES), help="one class only")
    args = p.parse_args(list(argv))
    if args.seeds < 1:
        p.error(f"--seeds must be >= 1, got {args.seeds}")
    ok = True
    print(f"{'class':32s} {'runs':>5s} {'covered':>8s} {'within 1 %':>10s} {'clear':>6s} {'clear, covered':>15s}")
    for name, make in CLASSES.items():
        if args.only and name != args.only:
            continue
        covered = close = clear = clear_covered = 0
        for seed in range(args.seeds):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                est = fit(make(seed))
            ci = est.confidence_interval(0.95)
            hit = ci["a"][0] <= A <= ci["a"][1] and ci["b"][0] <= B <= ci["b"][1]
            covered += hit
            close += abs(est.a / A - 1) <= 0.01 and abs(est.b / B - 1) <= 0.01
            called = bool(est.selection and est.selection.clear)
            clear += called
            clear_covered += called and hit
        share = covered / args.seeds
        clear_share = clear_covered / clear if clear else 1.0
        met = share >= COVERAGE_GOAL and clear_share >= COVERAGE_GOAL
        ok &= met
        print(f"{name:32s} {args.seeds:5d} {100 * share:7.0f} % {100 * close / args.seeds:9.0f} % {clear:6d} "
              f"{100 * clear_share:14.0f} %   goal >= {100 * COVERAGE_GOAL:.0f} % both: {'met' if met else 'MISSED'}")
    return 0 if ok else 1
