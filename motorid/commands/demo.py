"""The article's section 5 on the simulated bench: four sines, every method, Table 1 with the truth.

Defaults (each a flag of ``motorid demo``): a = 25 1/s, b = 3 (rad/s^2)/duty,
sample period 5 ms, 16667 counts/rev, 10 s per run, inputs ``200 sin(omega t)``
for omega = 10, 20, 30, 40 rad/s (article eqs. 29-32, alpha = 0), noise-free.

Then the article's next step (its section 6), closed: a one-step MPC tracking a sine
speed reference on the same bench, designed from the true model, from the article's
``euler-ls`` estimate and from ``oe``'s (both of the first input), with the tracking
error RMS each design predicts and the one measured.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path
from typing import Sequence

from identify import NotIdentifiableError, available_methods, fit
from identify.estimate import Estimate
from motorid.arguments import CommandError, add_bench_arguments, add_knob_flag, sim_rig_from_args, warn_if_clipped
from motorid.progress import ProgressBar
from motorid.ranges import BENCH_RULES, check_bench_flags
from motorsim.excitation import Sine
from motorsim.files import write_atomically
from motorsim.knobs import knobs_of
from motorsim.recording import Recording
from motorsim.rig import Experiment, Rig
from motorsim.writing import write_recording

#: Methods whose simulated speed ``overlay.png`` draws over the measured one: the article's
#: Euler least squares and the output-error fit (all methods run when neither did).
OVERLAID_METHODS = ("euler-ls", "oe")

__all__ = ["OVERLAID_METHODS", "DemoRow", "article_experiments", "run_article", "format_table",
           "add_demo_arguments", "run_demo"]


@dataclasses.dataclass(frozen=True)
class DemoRow:
    """One cell block of the table: one input, one method."""

    input_name: str
    frequency: float
    method: str
    estimate: Estimate | None
    error: str = ""

    def relative_error(self, name: str, truth: float) -> float:
        """``(estimate - truth) / truth`` of parameter ``name`` (nan if the fit failed)."""
        return math.nan if self.estimate is None else self.estimate.value(name) / truth - 1.0


def article_experiments(frequencies: Sequence[float] = (10, 20, 30, 40), amplitude: int = 200,
                        phase: float = 0.0, sample_period: float = 0.005,
                        duration: float = 10.0) -> list[Experiment]:
    """The article's inputs ``eta_i = amplitude sin(omega_i t + phase)`` (eqs. 29-32)."""
    return [Experiment(Sine(f, amplitude, phase), sample_period, duration) for f in frequencies]


def run_article(rig: Rig, experiments: Sequence[Experiment], methods: Sequence[str] | None = None,
                progress: bool | None = None) -> tuple[list[Recording], list[DemoRow]]:
    """Run each experiment on ``rig`` and fit it with each method (failures are rows, not crashes).

    A progress bar on stderr counts the runs and fits (``progress``: None draws it when stderr
    is a terminal, True or False force it).
    """
    methods = list(methods or available_methods(open_loop=True, first_order=True))
    recordings, rows = [], []
    with ProgressBar(len(experiments) * (1 + len(methods)), "demo", unit="steps", enabled=progress) as bar:
        for i, exp in enumerate(experiments, 1):
            bar.update(0, f"eta_{i}: simulating")
            rec = rig.run(exp)
            recordings.append(rec)
            bar.update(1)
            frequency = float(getattr(exp.excitation, "frequencies", (math.nan,))[0])
            for m in methods:
                bar.update(0, f"eta_{i}: {m}")
                try:
                    rows.append(DemoRow(f"eta_{i}", frequency, m, fit(rec, method=m)))
                except NotIdentifiableError as exc:
                    rows.append(DemoRow(f"eta_{i}", frequency, m, None, str(exc)))
                bar.update(1)
    return recordings, rows


def format_table(rows: Sequence[DemoRow], a: float, b: float) -> str:
    """The article's Table 1 with a truth column and each method's error."""
    head = (f"{'input':<7} {'omega':>6} {'method':<12} {'a [1/s]':>10} {'true a':>8} {'a err %':>9} "
            f"{'b':>9} {'true b':>7} {'b err %':>9} {'fit %':>7}")
    lines = [head, "-" * len(head)]
    for r in rows:
        if r.estimate is None:
            lines.append(f"{r.input_name:<7} {r.frequency:>6g} {r.method:<12} failed: {r.error}")
            continue
        e = r.estimate
        lines.append(f"{r.input_name:<7} {r.frequency:>6g} {r.method:<12} {e.a:>10.4f} {a:>8g} "
                     f"{100 * r.relative_error('a', a):>+9.3f} {e.b:>9.5f} {b:>7g} "
                     f"{100 * r.relative_error('b', b):>+9.3f} {e.fit_percent:>7.2f}")
    return "\n".join(lines)


def add_demo_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid demo``: the bench (a = 25, b = 3 by default), the sines, ``--out``."""
    add_bench_arguments(parser, BENCH_RULES, a=25.0, b=3.0)
    g = parser.add_argument_group("experiments")
    for k in knobs_of(Experiment):
        if k.name in ("sample_period", "duration"):
            add_knob_flag(g, k, rule=BENCH_RULES[k.name])
    g.add_argument("--frequencies", default="10,20,30,40", metavar="W,W,...",
                   help="sine frequencies in rad/s (default 10,20,30,40)")
    g.add_argument("--amplitude", type=int, default=200, help="sine amplitude in duty (default 200)")
    g.add_argument("--phase", type=float, default=0.0, help="sine phase alpha in rad (default 0)")
    parser.add_argument("--methods", default=None, metavar="M,M,...", help="methods to compare (default: all)")
    parser.add_argument("--out", default="demo-output", metavar="DIR",
                        help="where the table, recordings and figures go (default demo-output)")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    c = parser.add_argument_group("closed loop")
    c.add_argument("--reference", default=None, metavar="KIND:ARGS",
                   help="speed reference of the closed-loop part in rad/s (default sine:30,10)")
    c.add_argument("--duty-weight", dest="duty_weight", type=float, default=None, metavar="LAMBDA",
                   help="the MPC's weight of u^2 in (rad/s)^2 per duty^2 (default 1e-4)")
    c.add_argument("--no-control", action="store_true", help="skip the closed-loop part")


def _closed_loop_flags(args: argparse.Namespace) -> None:
    """Refuse the closed-loop flags with ``--no-control`` (they would be ignored); else fill in their defaults."""
    given = [flag for flag, name in (("--reference", "reference"), ("--duty-weight", "duty_weight"))
             if getattr(args, name) is not None]
    if args.no_control and given:
        raise CommandError(f"{', '.join(given)} set{'s' if len(given) == 1 else ''} the closed-loop part, and "
                           "--no-control skips it: give one or the other")
    args.reference = "sine:30,10" if args.reference is None else args.reference
    args.duty_weight = 1e-4 if args.duty_weight is None else args.duty_weight


def run_demo(args: argparse.Namespace) -> int:
    """Run the article's experiments, print and write Table 1, the recordings and the figures."""
    _closed_loop_flags(args)
    try:
        freqs = [float(x) for x in args.frequencies.split(",")]
    except ValueError:
        freqs = []
    if not freqs or not all(math.isfinite(w) and w > 0 for w in freqs):   # an empty item is refused, not skipped
        raise CommandError(f"--frequencies must be comma-separated numbers > 0 in rad/s, none left empty, "
                           f"got {args.frequencies!r}")
    methods = args.methods.split(",") if args.methods else None
    for m in methods or []:
        if m not in available_methods():
            raise CommandError(f"--methods must name methods among {available_methods()}, got {m!r}")
    check_bench_flags(args)
    rig = sim_rig_from_args(args)
    exps = article_experiments(freqs, args.amplitude, args.phase, args.sample_period, args.duration)
    if exps:
        warn_if_clipped(exps[0], f"--amplitude {args.amplitude}")
    recordings, rows = run_article(rig, exps, methods)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = format_table(rows, args.a, args.b)
    print(f"Article Table 1 on the simulated bench: a = {args.a:g} 1/s, b = {args.b:g} (rad/s^2)/duty, "
          f"dt = {args.sample_period:g} s, {args.counts_per_rev} counts/rev, {args.duration:g} s per run\n")
    print(table)
    write_atomically(out / "table.txt", table + "\n")
    for i, rec in enumerate(recordings, 1):
        write_recording(rec, out / f"eta_{i}.csv")
    summary = [{"input": r.input_name, "frequency": r.frequency, "method": r.method,
                "error": r.error or None, **(r.estimate.to_dict() if r.estimate else {})} for r in rows]
    write_atomically(out / "table.json", json.dumps({"true_a": args.a, "true_b": args.b, "rows": summary}, indent=1))
    if not args.no_plots:
        from motorid import plots
        sines = [f"eta_{i} = {args.amplitude} sin({freqs[i - 1]:g} t)" for i in range(1, len(recordings) + 1)]
        paths = []
        for i, (rec, sine) in enumerate(zip(recordings, sines), 1):
            paths.append(out / f"figure_{i}.png")
            plots.plot_run(rec, paths[-1], title=f"Figure {i}: {sine} and the measured speed ω")
        ran = list(dict.fromkeys(r.method for r in rows))
        shown = [m for m in OVERLAID_METHODS if m in ran] or ran
        fits = [{r.method: r.estimate for r in rows if r.input_name == f"eta_{i}" and r.method in shown}
                for i in range(1, len(recordings) + 1)]
        paths.append(out / "overlay.png")
        plots.plot_overlay(recordings, fits, paths[-1], labels=sines)
        print("\nfigures: " + ", ".join(str(p) for p in paths))
    print(f"table, recordings: {out / 'table.txt'}, {out / 'table.json'}, {out}/eta_*.csv")
    if not args.no_control:
        run_closed_loop_part(args, rig, rows, out)
    return 0


def run_closed_loop_part(args: argparse.Namespace, rig: Rig, rows: Sequence[DemoRow], out: Path) -> None:
    """One-step MPC designed from the truth, ``euler-ls`` and ``oe`` (first input), run on ``rig``."""
    from motorid.commands.control import compare_designs, format_closed_loop_table
    from motorid.ranges import check_reference_times
    from motorsim.control import PlantModel, parse_reference
    first = {r.method: r.estimate for r in rows if r.input_name == "eta_1" and r.estimate is not None}
    from motorsim.rig import SimRig
    # the simulated rig's own plant, every part of it (a dead zone, static friction, an electrical lag too)
    truth = (PlantModel.from_source(rig.motor, args.sample_period, args.counts_per_rev) if isinstance(rig, SimRig)
             else PlantModel(args.a, args.b, args.sample_period, args.counts_per_rev, friction=args.friction,
                             bias=args.bias, input_delay=args.input_delay))
    designs = [("truth", truth)] + [(m, first[m]) for m in ("euler-ls", "oe") if m in first]
    reference = check_reference_times(parse_reference(args.reference), args.sample_period)
    closed = compare_designs(rig, designs, "mpc", reference, args.duration, args.sample_period, args.counts_per_rev,
                             duty_weight=args.duty_weight)
    table = format_closed_loop_table(closed)
    print(f"\nClosed loop (the article's section 6): one-step MPC, lambda = {args.duty_weight:g} (rad/s)^2/duty^2, "
          f"reference {reference.describe()} rad/s, {args.duration:g} s, designed from each model "
          f"(estimates of eta_1)\n")
    print(table)
    write_atomically(out / "closed_loop.txt", table + "\n")
    for row in closed:
        write_recording(row.recording, out / f"closed_loop_{row.design}.csv")
    if not args.no_plots:
        from motorid import plots
        path = out / "closed_loop.png"
        plots.plot_tracking(closed, path, title="one-step MPC designed from each model, on the same bench")
        print(f"\nfigure: {path}")
    print(f"closed-loop table, recordings: {out / 'closed_loop.txt'}, {out}/closed_loop_*.csv")


def _best_method(methods: Sequence[str] | None) -> str:
    """The estimate the closed loop is designed from: ``oe``'s (the article's setting is linear), else the last."""
    if not methods or "oe" in methods:
        return "oe"
    return methods[-1]
