"""``motorid live --until PCT``: runs on the bench, designed round by round, until a and b are as tight as asked.

The loop is :func:`identify.adaptive.run_until` on the opened serial rig (the real Arduino,
``fake://``, ``avr-sim://``): a ranging opening (or a sine for ``--a/--b`` or ``--model``), then
rounds of the default estimator on every run so far and the block predicted to shrink the
intervals fastest, until both 95 % intervals are within ``+-PCT`` % and the structure is a clear
choice, or the budget (``--max-time``, ``--max-speed``, ``--max-travel``) says no.  Each round
prints one line; every run is kept in one recording (``--out``), written when the loop ends
(the runs so far, marked incomplete, when it is interrupted); ``--save`` writes the model as
``motorid identify --save`` does.
"""
from __future__ import annotations

import argparse
import json
import math
from typing import Callable

from motorid.arguments import CommandError, print_to_stderr

__all__ = ["add_until_arguments", "run_live_until", "check_until_flags"]


def add_until_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of ``live --until``."""
    from identify.adaptive import DEFAULT_MAX_TIME
    g = parser.add_argument_group("until confident (--until)")
    g.add_argument("--until", type=float, default=None, metavar="PCT",
                   help="run rounds of experiments, each designed from the estimate so far, until the 95 %% "
                        "intervals of a and b are both within ±PCT %% of their values (0 < PCT < 100); without "
                        "--a/--b or --model a ranging opening finds the break-away duty and a first a and b")
    g.add_argument("--max-time", dest="max_time", type=float, default=None, metavar="S",
                   help=f"motor-time budget of --until in s (default {DEFAULT_MAX_TIME:g})")
    g.add_argument("--max-speed", dest="max_speed", type=float, default=None, metavar="RAD_S",
                   help="largest shaft speed --until may ask for, rad/s (default: only the duty limit)")
    g.add_argument("--max-travel", dest="max_travel", type=float, default=None, metavar="RAD",
                   help="largest swing of the shaft angle --until may ask for, rad (default: none)")
    g.add_argument("--save", metavar="MODEL.json", default=None,
                   help="with --until: write the model as motorid identify --save does")


_UNTIL_ONLY = ("max_time", "max_speed", "max_travel", "save")


def check_until_flags(args: argparse.Namespace) -> None:
    """Refuse a bad target or budget (naming the flag, the rule and the value), and flags that need --until."""
    if args.until is None:
        given = [f"--{n.replace('_', '-')}" for n in _UNTIL_ONLY if getattr(args, n, None) is not None]
        if given:
            raise CommandError(f"{', '.join(given)} {'applies' if len(given) == 1 else 'apply'} only with --until PCT")
        return
    if not (math.isfinite(args.until) and 0 < args.until < 100):
        raise CommandError(f"--until must be a percentage in (0, 100), got {args.until!r}")
    for name, unit in (("max_time", "s"), ("max_speed", "rad/s"), ("max_travel", "rad")):
        value = getattr(args, name)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise CommandError(f"--{name.replace('_', '-')} must be a finite number of {unit} > 0, got {value!r}")
    if args.max_time is not None and args.max_time < 2 * args.sample_period * 40:
        raise CommandError(f"--max-time must leave room for one block of 40 samples twice "
                           f"(>= {80 * args.sample_period:g} s at --sample-period {args.sample_period:g}), "
                           f"got {args.max_time!r}")
    _check_until_companions(args)


def _check_until_companions(args: argparse.Namespace) -> None:
    """Refuse the flags --until replaces (a controller, an excitation, a model beyond a and b) or half a guess."""
    if getattr(args, "controller", None):
        raise CommandError("--until designs open-loop excitations: leave out --controller")
    from motorid.arguments import EXCITATION_FLAGS
    given = [f"--{n}" for n in EXCITATION_FLAGS if getattr(args, n.replace("-", "_"), None) is not None]
    if args.excitation is not None:
        given.append("--excitation")
    if given:
        raise CommandError(f"--until chooses the excitation round by round: leave out {', '.join(given)}")
    for name in ("friction", "bias", "input_delay", "electrical_time_constant"):
        if getattr(args, name, None) is not None:
            raise CommandError(f"--{name.replace('_', '-')} does not apply to --until: give the guess as --a and "
                               f"--b, or --model FILE.json")
    if (args.a is None) != (args.b is None) and not args.model:
        raise CommandError("--until's guess needs both --a and --b (or --model FILE.json), got only "
                           f"{'--a' if args.a is not None else '--b'}")
    if args.model and (args.a is not None or args.b is not None):
        raise CommandError("--model gives --until's guess, and --a/--b would be ignored: give one of them")
    if args.a is not None and not (math.isfinite(args.a) and args.a > 0):
        raise CommandError(f"--a must be a finite pole > 0 in 1/s, got {args.a!r}")
    if args.b is not None and not (math.isfinite(args.b) and args.b != 0):
        raise CommandError(f"--b must be a finite nonzero gain, got {args.b!r}")


def _guess(args: argparse.Namespace) -> tuple[float, float] | None:
    if args.model:
        from motorid.commands.control import load_model_file
        est = load_model_file(args.model)
        if est.input_unit != "duty":
            raise CommandError(f"--model {args.model}: its input is in {est.input_unit}, but the bench's is duty")
        if not (est.a > 0 and est.b != 0 and math.isfinite(est.a) and math.isfinite(est.b)):
            raise CommandError(f"--model {args.model}: a = {est.a!r}, b = {est.b!r} is no stable motor to start from")
        return float(est.a), float(est.b)
    if args.a is not None:
        return float(args.a), float(args.b)
    return None


def open_rig(args: argparse.Namespace):
    """The rig of ``live``'s flags (``--port``, ``--baud``, ...), opened; a port that cannot be opened is one
    line (:class:`CommandError`).  ``live`` with and without ``--until`` opens it here."""
    import identify.model_structures  # noqa: F401 - registers the structures a fake:// port's plant may name
    from hardware.errors import RigError
    from hardware.serial_rig import MAX_BAUDRATE, MAX_TIMEOUT, SerialRig
    if not 1 <= args.baud <= MAX_BAUDRATE:
        raise CommandError(f"--baud must be a line rate in 1...{MAX_BAUDRATE} baud, got {args.baud!r}")
    if not (math.isfinite(args.timeout) and 0 < args.timeout < MAX_TIMEOUT):
        raise CommandError(f"--timeout must be a number of seconds > 0 and < {MAX_TIMEOUT:g} (an hour without a "
                           f"sample is a device that is gone), got {args.timeout!r}")
    rig = SerialRig(args.port, args.baud, counts_per_rev=args.counts_per_rev, decoding=args.decoding,
                    watchdog_ms=args.watchdog_ms, timeout=args.timeout)
    try:
        rig.open()
    except RigError as exc:
        raise CommandError(str(exc)) from None
    return rig


def run_live_until(args: argparse.Namespace, default_out_path: Callable[[], str]) -> int:
    """The ``--until`` loop on the opened rig; 0 when the target is reached, 3 when it stopped short.

    ``default_out_path`` names the recording when ``--out`` is not given (``live``'s rule).
    """
    from hardware.errors import RigError
    from hardware.protocol import DEVICE_INPUT_DELAY
    from identify.adaptive import DEFAULT_MAX_TIME, run_until
    from motorid.progress import ProgressBar
    from motorsim.files import check_output_path
    say = print_to_stderr if args.json else print
    guess = _guess(args)
    named = args.out is not None
    if not named:
        args.out = default_out_path()
    check_output_path(args.out, flag="--out", suffixes=None) if args.overwrite else _refuse_existing(args.out)
    if args.save:
        check_output_path(args.save, flag="--save", inputs=[args.out])
    if args.plot:
        check_output_path(f"{args.out}.until.png", flag="--plot (its figure FILE.csv.until.png)")
    rig = open_rig(args)
    if not named:
        print_to_stderr(f"recording to {args.out}")
    runs: list = []

    def run(r, experiment):
        bar = ProgressBar(experiment.n_samples, "run", unit="samples", interval=0.25,
                          enabled=None if not args.quiet and not args.json else False)
        try:
            rec = r.run(experiment, on_sample=lambda s: bar.set(s.seq + 1))
        finally:
            bar.close()
        runs.append(rec)
        return rec

    def on_round(rnd) -> None:
        if not args.quiet:
            print_to_stderr(rnd.line(args.until))
            print_to_stderr(f"          {rnd.why}")

    max_time = DEFAULT_MAX_TIME if args.max_time is None else args.max_time
    try:
        with rig:
            result = run_until(rig, args.until, sample_period=args.sample_period, duty_limit=args.duty_limit,
                               max_time=max_time, max_speed=args.max_speed, max_travel=args.max_travel,
                               guess=guess, fit_options={"input_delay": DEVICE_INPUT_DELAY},
                               input_delay=DEVICE_INPUT_DELAY, on_round=on_round, run=run)
    except BaseException as exc:      # a rig error, Ctrl-C: keep the runs that arrived, the one cut short too
        partial = getattr(exc, "recording", None)
        if partial is not None and len(partial) > 1 and (not runs or partial is not runs[-1]):
            runs.append(partial)
        kept = _keep_runs(runs, args.out, f"{type(exc).__name__}: {exc}")
        if isinstance(exc, RigError):
            raise CommandError(f"{exc}; {kept}" if kept else str(exc)) from None
        if kept:
            print_to_stderr(f"motorid: {kept}")
        raise
    return _report(args, result, say)


def _refuse_existing(path: str) -> None:
    import os

    from motorsim.files import check_output_path
    if os.path.lexists(path):
        raise CommandError(f"--out {path} exists; give --overwrite to replace it, or another --out")
    check_output_path(path, flag="--out")


def _keep_runs(runs: list, path: str, reason: str) -> str:
    """Write the runs that arrived, marked incomplete; say where."""
    if not runs:
        return ""
    from identify.adaptive import join_runs
    from motorsim.recording import Recording
    from motorsim.writing import write_recording
    rec = join_runs(runs)
    meta = {**rec.metadata, "complete": "false", "incomplete_reason": " ".join(reason.split())}
    rec = Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, counts=rec.counts, seq=rec.seq,
                    counts_per_rev=rec.counts_per_rev, metadata=meta)
    try:
        write_recording(rec, path, at_once=True)
    except OSError as exc:
        return f"the {len(runs)} runs could not be written to {path} ({exc})"
    return f"the {len(runs)} runs that arrived are in {path} (complete: false)"


def _report(args: argparse.Namespace, result, say) -> int:
    """Write the recording (and the model), print the outcome; 0 when the target was reached, else 3."""
    from motorid.commands.identify import format_estimate
    from motorsim.files import write_atomically
    from motorsim.writing import write_recording
    rec = result.recording
    meta = {**rec.metadata, "until_target_pct": repr(result.target), "until_stop": result.stop,
            "until_reason": " ".join(result.reason.split())}
    from motorsim.recording import Recording
    rec = Recording(time=rec.time, duty=rec.duty, sample_period=rec.sample_period, counts=rec.counts, seq=rec.seq,
                    counts_per_rev=rec.counts_per_rev, metadata=meta)
    path = write_recording(rec, args.out, at_once=True)   # the data, kept whatever follows
    say(f"wrote {len(rec)} samples of {len(result.rounds)} runs to {path}")
    est = result.estimate
    if est is not None:
        say(format_estimate(est))
        if args.save:
            from identify.estimate import with_data_files
            est = with_data_files(est, [str(path)])
            write_atomically(args.save, est.to_json() + "\n")
            say(f"model       {args.save}")
    verdict = "reached" if result.reached else "stopped short"
    clear = "a clear choice" if result.clear else "NOT a clear choice"
    structure = f"the model '{est.structure}' is {clear}" if est is not None else "no model"
    say(f"until       {verdict}: {result.reason}")
    say(f"            {structure}; motor time {result.motor_time:.4g} s in {len(result.rounds)} rounds"
        + (f"; break-away duty {result.breakaway:g}" if result.breakaway is not None else ""))
    if est is not None:
        say("            the 95 % intervals (and the standard errors, the saved covariance) hold a and b at once: "
            "each at 97.5 %, as the stop needs both")
    if args.plot:
        from motorid.plots import plot_until
        plot_until(result, f"{args.out}.until.png")
        say(f"figure      {args.out}.until.png")
    if args.json:
        out = {**result.to_dict(), "recording": str(path),
               "estimate": None if est is None else est.to_dict()}
        print(json.dumps(out))
    return 0 if result.reached else 3
