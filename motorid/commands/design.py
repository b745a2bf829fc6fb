"""``motorid design``: the sine that pins down a and b best, next to the article's four, and a multisine.

The computations are :func:`identify.checks.design.design_sine` and :func:`identify.checks.design.design_multisine`;
this module is their command line.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from identify.checks.design import SineDesign, design_multisine, design_sine
from motorsim.files import make_output_dir, write_atomically

__all__ = ["format_design", "add_design_arguments", "run_design"]


def format_design(design: SineDesign) -> str:
    """The recommendation next to the article's sines, as a table."""
    head = f"{'sine':<22} {'se(a) [1/s]':>12} {'se(a)/a':>9} {'se(b)':>11} {'se(b)/b':>9}"
    lines = [head, "-" * len(head)]

    def line(label, p):
        r = p.relative_stderr
        return f"{label:<22} {p.stderr_a:>12.3g} {100 * r['a']:>8.3g}% {p.stderr_b:>11.3g} {100 * r['b']:>8.3g}%"
    best = design.best
    lines.append(line(f"{best.amplitude} sin({best.frequency:.4g} t) *", best))
    for p in design.article:
        lines.append(line(f"{p.amplitude} sin({p.frequency:g} t)", p))
    return "\n".join(lines)


def add_design_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid design``."""
    parser.add_argument("--a", type=float, required=True, help="rough guess of the pole a in 1/s")
    parser.add_argument("--b", type=float, required=True, help="rough guess of the gain b in (rad/s^2)/duty")
    parser.add_argument("--sample-period", type=float, required=True, metavar="S", help="sample period in s")
    parser.add_argument("--counts-per-rev", type=int, required=True, metavar="N",
                        help="encoder counts per revolution after quadrature decoding [counts/rev]")
    parser.add_argument("--angle-noise", type=float, default=0.0, metavar="RAD",
                        help="std of the angle noise in rad, besides quantisation (default 0)")
    parser.add_argument("--duration", type=float, default=10.0, metavar="T", help="length of the run in s (default 10)")
    parser.add_argument("--duty-limit", type=int, default=255, metavar="N",
                        help="duty clamp, 1...255 [duty] (default 255)")
    parser.add_argument("--out", default="design-output", metavar="DIR",
                        help="folder for design.json and design.png (default design-output)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG")
    parser.add_argument("--precision", type=float, default=None, metavar="PCT",
                        help="target relative standard error of the frequency response at every line of the "
                             "recommended multisine [%%] (default: the precision of the whole --duration)")


def run_design(args: argparse.Namespace) -> int:
    """``motorid design``: recommend a sine and compare it with the article's four."""
    design = design_sine(args.a, args.b, args.sample_period, counts_per_rev=args.counts_per_rev,
                         angle_noise=args.angle_noise, duration=args.duration, duty_limit=args.duty_limit)
    b = design.best
    print(f"guesses a = {args.a:g} 1/s, b = {args.b:g} (rad/s^2)/duty; dt = {args.sample_period:g} s, "
          f"{args.counts_per_rev} counts/rev, angle noise {args.angle_noise:g} rad, {args.duration:g} s per run\n")
    print(f"recommended: {b.amplitude} sin({b.frequency:.4g} t)  (duty limit {args.duty_limit}); "
          "predicted Cramér-Rao standard errors:\n")
    print(format_design(design))
    ms = design_multisine(args.a, args.b, args.sample_period, counts_per_rev=args.counts_per_rev,
                          angle_noise=args.angle_noise, duration=args.duration, duty_limit=args.duty_limit,
                          precision=None if args.precision is None else args.precision / 100)
    print(f"\nfor the frequency response (motorid frequency): --excitation {ms.excitation.describe()} "
          f"--duration {ms.duration:g}\n  {ms.periods} periods, lines {ms.band[0]:.4g}-{ms.band[1]:.4g} rad/s; "
          f"response within {100 * ms.line_stderr:.3g} % (one standard error) at every line; "
          f"se(a)/a {100 * ms.stderr_a / args.a:.3g} %, se(b)/b {100 * ms.stderr_b / abs(args.b):.3g} %")
    if args.precision is not None and ms.line_stderr > args.precision / 100:
        print(f"  the target {args.precision:g} % needs a longer --duration than {args.duration:g} s")
    out = Path(args.out)
    make_output_dir(out)
    write_atomically(out / "design.json", json.dumps({**design.to_dict(), "multisine": ms.to_dict()}, indent=1))
    paths = [out / "design.json"]
    if not args.no_plots:
        from motorid import plots
        f = np.array([p.frequency for p in design.scan])
        paths.append(out / "design.png")
        plots.plot_design(
            f, [100 * p.relative_stderr["a"] for p in design.scan], [100 * p.relative_stderr["b"] for p in design.scan],
            paths[-1], marks=[(b.frequency, "recommended"), *((p.frequency, f"article {p.frequency:g}")
                                                               for p in design.article)],
            title=f"predicted standard error, {args.duty_limit} sin(ω t), a={args.a:g}, b={args.b:g}, "
                  f"dt={args.sample_period:g} s")
    print("\nwrote " + ", ".join(str(p) for p in paths))
    return 0
