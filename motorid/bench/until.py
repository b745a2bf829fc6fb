"""``motorid bench until``: motor time to a target precision, the adaptive run against fixed experiments.

On seeded simulated rigs (:func:`until_rig`: ``a`` from 2 to 150 1/s, log-uniform; ``b`` giving
15-60 rad/s at duty 200; one rig in four plain, with Coulomb friction, with an input delay of
1-3 samples, or behind a driver lag of 0.5-2 ms; 1000 counts with 10 mrad of angle noise, about
3 rad/s of differenced speed noise at 5 ms), the motor time until both 95 % intervals of the
default estimator lie within ``+-target`` %, every experiment judged by the adaptive run's own
stopping rule (:func:`identify.adaptive.judge`: the same answer, its intervals widened for the two
at once, with a lag left free, the structure a clear choice; ``--rule plain``: the default's 95 %
intervals alone, as a user reading ``identify`` would):

- **adaptive**: :func:`identify.adaptive.run_until` (no guess: the ranging opening counts too);
- **oracle**, the baseline of the speed goal: the one fixed experiment of the loop's own family (a sine, or
  two lines of its shapes, the lag-pinning ratios included) that the Cramér-Rao bound of the true motor (its
  pole, gain, delay and friction known, a lag left free as the stopping rule leaves it) predicts to reach
  the target soonest (:func:`identify.adaptive.fixed_design_time`), first run at the length predicted;
- **best sine**: the sine :func:`identify.checks.design.design_sine` designs for the true motor;
- **article**: the article's four sines (10, 20, 30, 40 rad/s, duty 200), a quarter of the time each;
- **PRBS**: duty +-200, a bit held 10 ms.

A fixed experiment's time is found by running it: a first run, then runs of the length that the
fit's own intervals predict (their width falls as ``1/sqrt(T)``; twice as long after a run whose
structure is not a clear choice), up to four, each a fresh run from rest with fresh noise; the
shortest within target is the time (``-`` when none within the longest allowed run). Prints per rig
and the medians, the ratios adaptive / best sine and article / adaptive where the article reached
the target, and how often the adaptive run's intervals hold the built ``a`` and ``b`` (coverage
under its stopping rule). Goals: adaptive time at most 1.5 x the oracle's (where both reach the target,
the larger of the ratio of the medians and the median of the per-rig ratios; the ratio to the best sine
reported too), at least 2 x
faster than the article's four sines where they reach the target, coverage at least 93 %. Exits 1
when one is missed.

``motorid bench coverage --until`` runs the adaptive runs only and reports their coverage.
"""
from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
import warnings
from typing import Any, NamedTuple, Sequence

import numpy as np

from motorid.bench.flags import integer, reals
from motorsim.excitation import Excitation

__all__ = ["bench_until", "until_rig", "UntilOutcome", "until_run", "fixed_time", "UNTIL_COVERAGE_GOAL",
           "SPEED_GOAL", "ARTICLE_GOAL", "bench_until_coverage"]

#: Share of adaptive runs whose 95 % intervals must hold the built a and b.
UNTIL_COVERAGE_GOAL = 0.93
#: Median adaptive time / median best-sine time must be at most this.
SPEED_GOAL = 1.5
#: Median article time / adaptive time (where the article reaches the target) must be at least this.
ARTICLE_GOAL = 2.0
SAMPLE_PERIOD = 0.005
#: The longest run (s) a fixed experiment or the adaptive one may take, per target in %.
_LONGEST = {1.0: 60.0}


#: The fixed experiments timed: the fair baseline (``oracle``), the best sine, the article's four sines, a PRBS.
FIXED = ("oracle", "best", "article", "prbs")


def _longest(target: float) -> float:
    return _LONGEST.get(target, min(600.0, 60.0 * (1.0 / target) ** 2))


class RigSpec(NamedTuple):
    """A benchmark rig: the motor's numbers and its kind."""

    a: float
    b: float
    kind: str
    friction: float
    input_delay: int
    lag: float


def rig_spec(seed: int) -> RigSpec:
    """The motor of rig ``seed`` (module docstring)."""
    rng = np.random.default_rng([7039, seed])
    a = float(math.exp(rng.uniform(math.log(2.0), math.log(150.0))))
    b = a * float(rng.uniform(15.0, 60.0)) / 200.0
    kind = ("plain", "friction", "delay", "lag")[seed % 4]
    friction = float(rng.uniform(0.05, 0.2)) * b * 200 if kind == "friction" else 0.0
    delay = int(rng.integers(1, 4)) if kind == "delay" else 0
    lag = float(rng.uniform(0.0005, 0.002)) if kind == "lag" else 0.0
    return RigSpec(a, b, kind, friction, delay, lag)


def until_rig(seed: int, noise_seed: int = 0):
    """The simulated rig of ``seed`` with its noise drawn from ``noise_seed`` (a fresh run, the same motor)."""
    from motorsim import Encoder, Motor, SimRig
    s = rig_spec(seed)
    motor = Motor(s.a, s.b, friction=s.friction, input_delay=s.input_delay, electrical_time_constant=s.lag)
    return SimRig(motor, Encoder(1000, angle_noise=1e-2), rng=np.random.default_rng([seed, noise_seed, 39]))


def _reach(est) -> float:
    """Largest relative distance of the 95 % intervals' ends of a and b from their values, in %."""
    ci = est.confidence_interval(0.95)
    out = 0.0
    for k in ("a", "b"):
        v = float(est.value(k))
        lo, hi = ci[k]
        r = 100 * max(v - lo, hi - v) / abs(v)
        out = max(out, r if math.isfinite(r) else math.inf)
    return out


#: How a fixed experiment is judged: ``until`` by the adaptive run's own stopping rule
#: (:func:`identify.adaptive.judge`: the same answer, its intervals widened for the two at once, a
#: lag left free, the structure a clear choice), ``plain`` by the default's 95 % intervals alone.
RULES = ("until", "plain")


def _fit_reach(recordings, rule: str = "until") -> tuple[float, bool]:
    """The reach (%) of a fixed experiment's runs, and whether it meets the rule at that reach."""
    from identify import fit
    from identify.adaptive import judge
    from identify.errors import NotIdentifiableError
    from motorsim.checks import ParameterError
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if rule == "until":
            j = judge(recordings)
            return j.worst, bool(j.clear)
        try:
            return _reach(fit(recordings, outliers="keep")), True
        except (NotIdentifiableError, ParameterError):
            return math.inf, True


def fixed_time(seed: int, kind: str, target: float, tries: int = 5, rule: str = "until") -> float:
    """Motor time of the fixed experiment ``kind`` (``best``, ``article``, ``prbs``) until within ``target`` %.

    A first run of 1 s, then runs of the length the last fit's intervals predict (their width falls
    as ``1/sqrt(T)``: ``T (reach / target)^2``, 5 % more), each a fresh run from rest: the shortest
    run found within target, ``inf`` when none is (at most the longest allowed).  The best sine is
    designed (:func:`identify.checks.design.design_sine`) for the true motor and each run's length.
    ``rule`` (:data:`RULES`): within target by the adaptive run's stopping rule (``until``, the
    default: the comparison on equal terms) or by the default's plain 95 % intervals (``plain``).
    """
    if rule not in RULES:
        raise ValueError(f"rule must be one of {RULES}, got {rule!r}")
    from identify.checks.design import ARTICLE_FREQUENCIES, design_sine
    from motorsim import PRBS, Experiment, Sine
    s = rig_spec(seed)
    longest = _longest(target)
    if kind not in FIXED:
        raise ValueError(f"kind must be one of {', '.join(FIXED)}, got {kind!r}")
    length, found = 1.0, math.inf
    if kind == "oracle":
        length = oracle_design(seed, target).duration
    parts: list[Excitation]
    for attempt in range(tries):
        if kind == "oracle":
            parts = [oracle_design(seed, target, length).excitation]
        elif kind == "best":
            d = design_sine(s.a, s.b, SAMPLE_PERIOD, counts_per_rev=1000, angle_noise=1e-2,
                            duration=max(length, 0.2), duty_limit=253, n_frequencies=16).best
            parts = [Sine(d.frequency, d.amplitude)]
        elif kind == "article":
            parts = [Sine(f, 200) for f in ARTICLE_FREQUENCIES]
        else:
            parts = [PRBS(200, -200, 12, 2, 1)]
        rig = until_rig(seed, 1000 + attempt)
        each = max(round(length / len(parts) / SAMPLE_PERIOD), 40) * SAMPLE_PERIOD
        recs = [rig.run(Experiment(x, SAMPLE_PERIOD, each)) for x in parts]
        reach, clear = _fit_reach(recs, rule)
        total = each * len(parts)
        if reach <= target and clear:
            found = min(found, total)
        if not math.isfinite(reach):
            break
        if not clear:           # the structure not a clear choice: a longer run, whatever its reach
            if total >= longest:
                break
            nxt = min(longest, 2 * max(total, total * (reach / target) ** 2))
        else:
            nxt = min(longest, max(0.2, total * (reach / target) ** 2 * 1.05))
        if (reach <= target and nxt >= 0.9 * total and clear) or (reach > target and total >= longest):
            break
        length = nxt
    return found


def oracle_design(seed: int, target: float, length: float | None = None):
    """The fair baseline's experiment for rig ``seed``: of the loop's own family (a sine or two lines of its
    shapes), designed by the Cramér-Rao bound for the true motor (its pole, gain, delay and friction known, a lag
    left free as the stopping rule leaves it: :func:`identify.adaptive.design_fixed`), for ``length`` s, or
    (None) for the shortest length predicted to reach ``target`` % (:func:`identify.adaptive.fixed_design_time`)."""
    from identify.adaptive import design_fixed, fixed_design_time
    s = rig_spec(seed)
    options: dict[str, Any] = dict(input_delay=s.input_delay, nuisance=("friction",) if s.friction else (),
                                   duty_limit=253, angle_noise=1e-2, counts_per_rev=1000)
    if length is None:
        return fixed_design_time(s.a, s.b, SAMPLE_PERIOD, target, _longest(target), **options)
    return design_fixed(s.a, s.b, SAMPLE_PERIOD, max(length, 0.2), **options)


class UntilOutcome(NamedTuple):
    """One adaptive run on one rig."""

    seed: int
    kind: str
    a: float
    target: float
    motor_time: float
    reached: bool
    covered: bool
    clear: bool
    rounds: int
    stop: str
    seconds: float


def until_run(seed: int, target: float) -> UntilOutcome:
    """The adaptive run on rig ``seed`` to ``target`` %, against the built motor."""
    from identify.adaptive import run_until
    s = rig_spec(seed)
    start = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_until(until_rig(seed), target, sample_period=SAMPLE_PERIOD, max_time=_longest(target))
    covered = False
    if result.estimate is not None:
        ci = result.estimate.confidence_interval(0.95)
        covered = bool(ci["a"][0] <= s.a <= ci["a"][1] and ci["b"][0] <= s.b <= ci["b"][1])
    return UntilOutcome(seed, s.kind, s.a, target, result.motor_time, result.reached, covered, result.clear,
                        len(result.rounds), result.stop, time.process_time() - start)


def _job(job: tuple, rule: str = "until") -> tuple:
    what, seed, target = job
    if what == "adaptive":
        return job, until_run(seed, target)
    return job, fixed_time(seed, what, target, rule=rule)


def _median(xs: list[float]) -> float:
    return statistics.median(xs) if xs else math.nan


def _fmt(x: float) -> str:
    return f"{x:8.3g}" if math.isfinite(x) else "       -"


def bench_until(argv: Sequence[str]) -> int:
    """Run the benchmark (module docstring); 0 when every goal holds."""
    p = argparse.ArgumentParser(prog="motorid bench until", description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=integer(), default=100, help="seeded rigs (default 100)")
    p.add_argument("--targets", type=reals(), default=[1.0], metavar="PCT[,PCT]",
                   help="targets in %% (default 1; 1,0.1 adds the ±0.1 %% runs, minutes per rig)")
    p.add_argument("--fixed-rigs", type=integer(0), default=None, metavar="N",
                   help="rigs on which the fixed experiments are timed too (default: all)")
    p.add_argument("--rule", choices=RULES, default="until",
                   help="how the fixed experiments are judged: until (default) by the adaptive run's own stopping "
                        "rule (the same answer and intervals, widened for both at once, a lag left free, the "
                        "structure clear); plain by the default's 95 %% intervals alone")
    p.add_argument("--fixed", type=_kinds, default=FIXED, metavar="KIND[,KIND]",
                   help=f"the fixed experiments timed (default {','.join(FIXED)}; the goals need oracle and article)")
    p.add_argument("--workers", type=integer(), default=None, metavar="N",
                   help="worker processes (default: every core available)")
    args = p.parse_args(list(argv))
    return _run(args.rigs, args.targets, args.rigs if args.fixed_rigs is None else args.fixed_rigs, args.workers,
                args.rule, args.fixed)


def _kinds(text: str) -> tuple[str, ...]:
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in FIXED]
    if bad or not kinds:
        raise argparse.ArgumentTypeError(f"must be among {','.join(FIXED)}, got {text!r}")
    return kinds


def bench_until_coverage(argv: Sequence[str]) -> int:
    """``motorid bench coverage --until``: the adaptive runs' coverage only."""
    p = argparse.ArgumentParser(prog="motorid bench coverage --until", description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=integer(), default=100, help="seeded rigs (default 100)")
    p.add_argument("--target", type=reals(), default=[1.0], metavar="PCT", help="target in %% (default 1)")
    p.add_argument("--workers", type=integer(), default=None, metavar="N")
    args = p.parse_args(list(argv))
    return _run(args.seeds, args.target, 0, args.workers)


def _run(n_rigs: int, targets: list[float], fixed_rigs: int, workers: int | None, rule: str = "until",
         kinds: Sequence[str] = FIXED) -> int:
    from scenarios.executors import points_executor, results_in_order
    for t in targets:
        if not 0 < t < 100:
            print(f"motorid bench until: --targets must be percentages in (0, 100), got {t!r}", file=sys.stderr)
            return 2
    jobs = [("adaptive", seed, t) for t in targets for seed in range(n_rigs)]
    jobs += [(k, seed, t) for t in targets for seed in range(min(fixed_rigs, n_rigs))
             for k in kinds]
    adaptive: dict[tuple[int, float], UntilOutcome] = {}
    fixed: dict[tuple[str, int, float], float] = {}
    start = time.perf_counter()
    with points_executor(workers, None) as (executor, window):
        for i, (job, out) in enumerate(results_in_order(executor, _job, [(j, rule) for j in jobs], window)):
            if isinstance(out, UntilOutcome):
                adaptive[(job[1], job[2])] = out
                print(f"rig {out.seed:3d} {out.kind:8s} a {out.a:7.3g}: {out.motor_time:7.3g} s, {out.rounds} rounds, "
                      f"{out.stop}, {'covered' if out.covered else 'NOT covered'}"
                      f"{'' if out.clear else ', not clear'}", file=sys.stderr, flush=True)
            else:
                fixed[job] = float(out)
                print(f"rig {job[1]:3d} {job[0]:8s} ±{job[2]:g} %: {_fmt(float(out)).strip()} s", file=sys.stderr,
                      flush=True)
            if (i + 1) % max(1, len(jobs) // 20) == 0 or i + 1 == len(jobs):
                print(f"until: {i + 1}/{len(jobs)} runs", file=sys.stderr, flush=True)
    ok = True
    for t in targets:
        outs = [adaptive[(seed, t)] for seed in range(n_rigs)]
        ok &= _report_target(t, outs, {(k, s): v for (k, s, tt), v in fixed.items() if tt == t}, rule, kinds)
    print(f"{len(jobs)} runs in {time.perf_counter() - start:.0f} s")
    return 0 if ok else 1


def _report_target(t: float, outs: list[UntilOutcome], fixed: dict[tuple[str, int], float],
                   rule: str = "until", kinds: Sequence[str] = FIXED) -> bool:
    """The table and the goals of one target; whether the goals hold."""
    judged = "the adaptive run's stopping rule" if rule == "until" else "the default's plain intervals"
    print(f"\ntarget ±{t:g} %  (motor seconds until both 95 % intervals are within it; the fixed experiments "
          f"judged by {judged})")
    print(f"{'rig':>4s} {'kind':8s} {'a 1/s':>7s} {'adaptive':>8s} {'rounds':>6s} {'oracle':>8s} {'best':>8s} "
          f"{'article':>8s} {'prbs':>8s}  covered")
    for o in outs:
        fx = [fixed.get((k, o.seed), math.nan) for k in FIXED]
        print(f"{o.seed:4d} {o.kind:8s} {o.a:7.3g} {_fmt(o.motor_time if o.reached else math.inf)} "
              f"{o.rounds:6d} {' '.join(_fmt(x) for x in fx)}  {'yes' if o.covered else 'NO'}"
              f"{'' if o.reached else '  (' + o.stop + ')'}{'' if o.clear else '  not clear'}")
    reached = [o for o in outs if o.reached]
    covered = sum(o.covered for o in outs) / len(outs)
    print(f"adaptive: reached {len(reached)} of {len(outs)}, median {_median([o.motor_time for o in reached]):.3g} s, "
          f"{_median([float(o.rounds) for o in outs]):.3g} rounds, covered {100 * covered:.1f} % "
          f"(goal >= {100 * UNTIL_COVERAGE_GOAL:.0f} %), {_median([o.seconds for o in outs]):.2g} s CPU per run")
    for kind in sorted({o.kind for o in outs}):
        of = [o for o in outs if o.kind == kind]
        print(f"  {kind:8s}: covered {sum(o.covered for o in of)} of {len(of)}, "
              f"median {_median([o.motor_time for o in of if o.reached]):.3g} s")
    ok = covered >= UNTIL_COVERAGE_GOAL
    timed = [o for o in outs if any((k, o.seed) in fixed for k in FIXED)]
    if not timed:
        return ok
    got = {k: {o.seed: fixed.get((k, o.seed), math.nan) for o in timed} for k in FIXED}
    for k in FIXED:
        if all(math.isnan(x) for x in got[k].values()):
            continue
        fin = [x for x in got[k].values() if math.isfinite(x)]
        print(f"{k:8s}: reached {len(fin)} of {len(timed)}, median {_median(fin):.3g} s")
    ratios = {}
    for k, name in (("best", "best sine"), ("oracle", "oracle")):
        both = [(o.motor_time, got[k][o.seed]) for o in timed if o.reached and math.isfinite(got[k][o.seed])]
        # on the rigs where both reach the target (a baseline that never does has no time to compare)
        # the goal on the larger of the ratio of the medians and the median of the per-rig ratios
        ratios[k] = max(_median([x for x, _ in both]) / _median([y for _, y in both]),
                        _median([x / y for x, y in both])) if both else math.nan
        if both:
            print(f"where adaptive and {name} both reach it ({len(both)} rigs): median adaptive "
                  f"{_median([x for x, _ in both]):.3g} s, {name} {_median([y for _, y in both]):.3g} s, "
                  f"median of the per-rig ratios {_median([x / y for x, y in both]):.3g} x")
    pairs = [(got["article"][o.seed], o.motor_time) for o in timed
             if o.reached and math.isfinite(got["article"][o.seed])]
    speedup = _median([art / ada for art, ada in pairs]) if pairs else math.nan
    ratio = ratios["oracle"]
    print(f"adaptive / oracle (where both reach it; the larger of the two medians' ratio and the median ratio)  "
          f"{ratio:6.3g} x   goal <= {SPEED_GOAL:g}: "
          f"{'met' if ratio <= SPEED_GOAL else 'MISSED'}   (adaptive / best sine {ratios['best']:.3g} x, reported)")
    print(f"article / adaptive (median over {len(pairs)} rigs where the article reaches it)  {speedup:6.3g} x   "
          f"goal >= {ARTICLE_GOAL:g}: {'met' if speedup >= ARTICLE_GOAL else 'MISSED'}")
    # a goal whose baseline was not timed is not judged (nan compares false: missed)
    return ok and (ratio <= SPEED_GOAL or "oracle" not in kinds) and \
        (not pairs or speedup >= ARTICLE_GOAL)
