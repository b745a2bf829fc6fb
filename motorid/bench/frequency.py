"""``motorid bench frequency``: the frequency response of a long run against plain scipy.signal estimates."""
from __future__ import annotations

import argparse
import functools
from typing import Sequence

from motorid.bench.flags import integer
from motorid.bench.goals import Goal, report
from motorid.bench.timing import interleaved_times, least_time

__all__ = ["bench_frequency", "goal_figures", "GOALS", "TIME_GOAL"]

#: Seconds of ``frequency_response`` (Welch, bounds and coherence) on 10^6 samples.
TIME_GOAL = Goal("frequency_response of 10^6 samples (bounds, coherence; worst of 2)", 3.0, "s")
GOALS = (TIME_GOAL,)


def bench_frequency(argv: Sequence[str]) -> int:
    """Seconds of ``frequency_response`` (Welch, with bounds and coherence) against scipy.signal.csd + welch.

    Both get the same recording (a PRBS run of ``--samples`` samples, encoder counts) and the same
    Hann segments with half overlap; the baseline is what one writes by hand: the forward-differenced
    speed, then ``csd(u, y)`` and ``welch(u)`` for ``G = S_uy / S_uu`` and ``welch(y)`` for the
    coherence.  The two responses are compared, so a fast wrong answer cannot pass unnoticed.
    """
    p = argparse.ArgumentParser(prog="motorid bench frequency", description=__doc__.splitlines()[0])
    p.add_argument("--samples", type=integer(), default=10**6, help="samples of the run (default 1000000)")
    p.add_argument("--segment", type=integer(2), default=4096, help="Welch segment length in samples (default 4096)")
    p.add_argument("--repeats", type=integer(), default=5, help="timings to take the median of (default 5)")
    args = p.parse_args(list(argv))
    seconds = _measure(args.samples, args.segment, args.repeats, verbose=True)
    return report([(TIME_GOAL, seconds)]) if args.samples == 10**6 else 0


def goal_figures() -> list[tuple[Goal, float]]:
    """The least CPU time on 10^6 samples, the worst of two runs (5 ms and a 16667-count encoder, 1 ms and
    1000 counts; ``motorid bench --check``)."""
    import numpy as np

    from identify.frequency.frequency_estimate import frequency_response
    from motorsim import PRBS, Encoder, Experiment, Motor, SimRig
    seconds = []
    for dt, cpr in ((0.005, 16667), (0.001, 1000)):
        rig = SimRig(Motor(25.0, 3.0), Encoder(cpr, angle_noise=1e-3), rng=np.random.default_rng(0))
        rec = rig.run(Experiment(PRBS(200, -200, 16, 1), dt, 10**6 * dt))
        seconds.append(least_time(functools.partial(frequency_response, rec, method="welch", segment=4096), 5))
    return [(TIME_GOAL, max(seconds))]


def _measure(samples: int, segment: int, repeats: int, verbose: bool) -> float:
    """Seconds of ``frequency_response``; with ``verbose``, the comparison with scipy printed."""
    import numpy as np
    from scipy import signal

    from identify.frequency.frequency_estimate import frequency_response
    from motorsim import PRBS, Encoder, Experiment, Motor, SimRig
    args = argparse.Namespace(samples=samples, segment=segment, repeats=repeats)
    dt = 0.005
    rig = SimRig(Motor(25.0, 3.0), Encoder(angle_noise=1e-3), rng=np.random.default_rng(0))
    rec = rig.run(Experiment(PRBS(200, -200, 16, 1), dt, args.samples * dt))
    angle = rec.measured_angle()
    if angle is None:  # pragma: no cover - SimRig always records counts
        raise RuntimeError("the simulated run has no angle")

    def ours():
        return frequency_response(rec, method="welch", segment=args.segment)

    def scipy_plain():
        v = np.diff(angle) / dt
        u = rec.duty[:-1].astype(float)
        kw = {"fs": 1 / dt, "nperseg": args.segment, "window": "hann"}
        _, suy = signal.csd(u, v, **kw)
        _, suu = signal.welch(u, **kw)
        _, syy = signal.welch(v, **kw)
        return suy / suu, np.abs(suy) ** 2 / (suu * syy)

    if not verbose:
        t_ours, = interleaved_times([ours], args.repeats)
        return t_ours
    t_ours, t_scipy = interleaved_times([ours, scipy_plain], args.repeats)
    frf = ours()
    g, coherence = scipy_plain()
    lines = slice(1, args.segment // 2)
    diff = float(np.max(np.abs(frf.response - g[lines][:len(frf)]) / np.abs(g[lines][:len(frf)])))
    print(f"samples                         {args.samples}  (segment {args.segment}, {len(frf)} lines, "
          f"resolution {frf.resolution:.3g} rad/s)")
    print(f"frequency_response (welch)      {t_ours:8.3f} s   response, 95 % bound, coherence")
    print(f"scipy.signal csd + 2 x welch    {t_scipy:8.3f} s   response and coherence")
    print(f"ratio                           {t_scipy / t_ours:8.2f} x  (scipy time / ours); "
          f"largest relative difference of the responses {diff:.1e}")
    return t_ours
