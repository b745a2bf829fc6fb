"""``motorid identify``: fit a and b to recordings, optionally validate on a held-out run."""
from __future__ import annotations

import argparse
import json
import math
from typing import TYPE_CHECKING, Any, Callable

from motorid.arguments import CommandError, print_to_stderr
from motorid.commands.importing import (
    add_column_arguments,
    column_flags_given,
    import_from_args,
    read_motorid_recording,
)
from motorid.progress import Ticker
from motorsim.recording import Recording

if TYPE_CHECKING:
    from identify.default.selection_report import SelectionReport

__all__ = ["add_identify_arguments", "run_identify", "estimator_options", "format_estimate", "format_validation",
           "in_speed_unit"]

#: Flags passed to the estimator: flag -> (keyword, value when the flag is not given).
_OPTION_FLAGS = {"--input-delay": ("input_delay", None), "--fix-bias": ("fix_bias", False)}


def _input_delay(text: str) -> int | str:
    if text == "auto":
        return "auto"
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"--input-delay must be 'auto' or an integer >= 0 (samples), got {text!r}")
    return value


def add_identify_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid identify``."""
    from identify import DEFAULT_METHOD, available_methods
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="recordings (format v1), or foreign files with the column flags; several are pooled")
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=[DEFAULT_METHOD, *available_methods()],
                        help=f"estimator (default {DEFAULT_METHOD}: the input delay 0-10 and the structure - linear, "
                             "bias, Coulomb friction, dead zone - chosen by evidence, as identify.fit does; "
                             "name a method to force it)")
    parser.add_argument("--input-delay", type=_input_delay, default=None, metavar="auto|N",
                        help="input delay in samples, or 'auto' to estimate it (default auto for every method that "
                             "can: one fit per candidate delay 0-10, as identify.fit does)")
    parser.add_argument("--fix-bias", action="store_true",
                        help="hold the constant acceleration (bias, rad/s^2) at 0 (auto: no bias candidate; "
                             "oe-friction)")
    parser.add_argument("--validate", metavar="TEST", help="held-out recording: NRMSE fit and residual tests")
    parser.add_argument("--report", metavar="FILE.png",
                        help="figure: measured vs model speed, residual autocorrelation and cross-correlation, "
                             "a Bode panel of data and model (on TEST, else on the first FILE)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON document on stdout (the human-readable text goes to stderr); it "
                             "counts each file's samples at the input limit, kept in the fit (saturated_samples)")
    parser.add_argument("--drop-outliers", action="store_true",
                        help="drop corrupted samples (implausible jumps, isolated residual outliers) as gaps, "
                             "refit and list them, instead of refusing the file")
    parser.add_argument("--save", metavar="MODEL.json",
                        help="write the model (parameters, covariance, delay, sample period in s, units, method, "
                             "data files with sha256) for Estimate.from_json")
    add_column_arguments(parser, required=False)


def read_inputs(paths: list[str], args: argparse.Namespace) -> list:
    """Recordings (format v1), or foreign files mapped by the column flags when any is given."""
    if column_flags_given(args):
        return [import_from_args(p, args) for p in paths]
    return [read_motorid_recording(p) for p in paths]


def _reader(args: argparse.Namespace) -> Callable[[str, bool], Recording] | None:
    """How ``identify`` reads its files: the column mapping when any column flag is given."""
    if not column_flags_given(args):
        return read_motorid_recording
    return lambda path, check_samples: import_from_args(path, args)


def estimator_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword options the flags give the estimator; a flag the method does not take is an error."""
    from identify import method_options
    accepted = method_options(args.method)
    options = {}
    for flag, (name, unset) in _OPTION_FLAGS.items():
        value = getattr(args, name)
        if value is unset:           # the method's own default (the input delay's: identify.data.DEFAULT_INPUT_DELAY)
            continue
        if name not in accepted:
            takes = f"its options are {', '.join(accepted)}" if accepted else "it takes no options"
            raise CommandError(f"{flag} is not supported by method {args.method!r}: {takes}")
        options[name] = value
    return options


def _input_delay_option(args: argparse.Namespace) -> Any:
    """The input delay the estimator was run with: the flag's, else the method's declared default (None: none)."""
    from identify import option_declarations
    given = estimator_options(args)
    if "input_delay" in given:
        return given["input_delay"]
    return next((o.default for o in option_declarations(args.method) if o.name == "input_delay"), None)


def run_identify(args: argparse.Namespace) -> int:
    """Fit, print the estimate (and the validation), write the report figure if asked.

    With ``--json`` standard output holds exactly one JSON document and the human text goes to
    standard error, so the output pipes into ``python -m json.tool`` or ``jq``.
    """
    from identify import validate
    from identify.estimate import json_ready
    from motorid.screening import read_and_fit
    say = print_to_stderr if args.json else print
    _say_estimate(args.files)
    with Ticker(f"identify: {args.method} fit on {len(args.files)} recording(s)"):   # a line only after 1 s
        est, recs, dropped = read_and_fit(args.files, args.method, estimator_options(args),
                                          drop_outliers=args.drop_outliers, read=_reader(args))
    for d in dropped:
        say(f"dropped     {d}")
    say(format_estimate(est))
    if args.save:
        from identify.estimate import with_data_files
        from motorsim.files import write_atomically
        est = with_data_files(est, [*args.files])
        write_atomically(args.save, est.to_json() + "\n")
        say(f"model       {args.save}")
    checks = None
    if est.selection is not None:
        from identify.default.selection import residual_checks
        checks = residual_checks(est, recs[0])
        say(format_selection(est.selection, checks))
    elif _input_delay_option(args) == "auto":
        say(f"delay       {est.input_delay} samples, the shortest within the noise of the best "
            "fit over 0-10 (--input-delay N fixes it)")
    out = est.to_dict()
    figures = in_speed_unit(est)
    if figures is not None:
        out["in_speed_unit"] = figures
    if checks is not None:
        out["residual_checks"] = checks
    if dropped:
        out["dropped_samples"] = {d.file: d.seq for d in dropped}
    saturated = {name: n for name, rec in zip(args.files, recs) if (n := rec.saturated_samples())}
    if saturated:            # kept in the fit (identify.data.saturation_note says why), counted per file
        out["saturated_samples"] = saturated
    report = None
    held_out = read_inputs([args.validate], args)[0] if args.validate else None
    if held_out is not None:
        report = validate(est, held_out)
        say(format_validation(report, args.validate))
        out.update(report.summary())
    if args.report:
        from motorid.plots import plot_validation
        if report is None:
            report = validate(est, recs[0])
        where = args.validate or args.files[0]
        frf, why = _frequency_response(held_out if held_out is not None else recs[0])
        plot_validation(report, est, args.report, title=f"{est.method} on {where}", frequency_response=frf)
        say(f"report      {args.report}" + (f" (no Bode panel: {why})" if frf is None else ""))
    if args.json:
        print(json.dumps(json_ready(out)))
    return 0


def _frequency_response(recording: Recording) -> tuple[Any, str]:
    """The report's Bode panel data, or None and why the recording cannot give one (too short, gaps, a step)."""
    from identify.errors import NotIdentifiableError
    from identify.frequency.frequency_estimate import frequency_response
    try:
        return frequency_response(recording), ""
    except NotIdentifiableError as exc:
        return None, str(exc)


#: Bytes of input above which identify says first how long it expects to take.
LONG_INPUT_BYTES = 10 << 20
#: Seconds per byte of a recording file: measured 1.0 s for a 10^6-row, 25 MB recording (read, screen,
#: the default fit of a linear motor, the outlier check; `motorid bench selection`), rounded up to 2x.
SECONDS_PER_BYTE = 8e-8


def _say_estimate(files: list[str]) -> None:
    """On large inputs, the expected time on stderr before the work starts (progress follows by the ticker)."""
    import os
    total = 0
    for name in files:
        try:
            total += os.stat(name).st_size
        except OSError:
            return                       # the reader names the problem
    if total > LONG_INPUT_BYTES:
        print_to_stderr(f"identify: {total / 2**20:.0f} MiB of recordings; expect about "
                        f"{max(1, round(SECONDS_PER_BYTE * total))} s (longer when friction is fitted)")


def format_selection(selection: SelectionReport, checks: dict[str, float]) -> str:
    """The ``model`` section: the chosen structure, the runner-up in plain words, the residual checks."""
    chosen = selection.chosen
    lines = [f"model       {chosen.structure}, input delay {chosen.input_delay} samples ({chosen.method}), "
             f"chosen as the simplest fit within the noise of the best; "
             + ("a clear choice" if selection.clear else "NOT a clear choice (see the note)")]
    other = selection.runner_up
    if other:
        if other.within_noise and selection.clear:      # the intervals hold it: no contradiction of "clear"
            words = "fits as well, its a and b within the chosen one's intervals: either gives the same answer"
        elif other.within_noise:
            words = "the data cannot tell it from the chosen one"
        else:
            words = f"fits worse by {other.statistic:.3g} noise units (the test's threshold is about 11)"
        lines.append(f"  runner-up {other.structure}, input delay {other.input_delay}: {words}")
    lines.append(f"  compared  {len(selection.candidates)} candidate fits (structure x input delay; --json lists them)")

    def verdict(p: float, good: str, bad: str) -> str:
        if not p == p:          # nan: e.g. the speed never changes sign
            return f"{good}: not testable"
        return f"{good if p >= 0.01 else bad} (p = {p:.2g})"
    lines.append("  residual  " + "; ".join([
        verdict(checks["whiteness_p"], "white", "NOT white"),
        verdict(checks["input_p"], "independent of the input", "CORRELATED with the input"),
        verdict(checks["sign_p"], "independent of sign(speed)", "CORRELATED with sign(speed): friction?")]))
    for check in selection.checks:
        lines.append(f"  parts     {check.describe()}")
    return "\n".join(lines)


def format_estimate(est) -> str:
    """Human-readable summary of an Estimate (value, standard error, 95 % interval) and its kS, kV, kA;
    for data in another speed unit (rpm, ...), the speed figures in that unit too."""
    from identify.feedforward import apart, feedforward_constants
    text = f"{est}\n{feedforward_constants(est).describe()}"
    figures = in_speed_unit(est)
    if figures is None:
        return text
    unit, u = figures["unit"], est.input_unit
    lo, hi = figures["b_ci95"]
    lines = [f"in {unit:<8} b/a {figures['static_gain']:.6g} {unit}/{u} (the steady speed per {u}); "
             f"b {figures['b']:.6g} {unit}/s per {u}, 95 % CI [{lo:.6g}, {hi:.6g}]"]
    if "residual_rms" in figures:
        lines.append(f"            residual {figures['residual_rms']:.3g} {unit} RMS")
    if "top_speed" in figures:
        lines.append(f"            top speed {figures['top_speed']:.5g} {unit} at the input limit "
                     f"{est.input_limit:g} {u} (b/a x limit, linear model)")
    ff = figures["feedforward"]
    lines.append("SysId      " + ", ".join(
        "{} {} [{}, {}] {}".format(k, *apart(ff[k], *ff[k + "_ci95"]), ff[k + "_unit"])
        if math.isfinite(ff[k + "_ci95"][0]) else f"{k} {ff[k]:.4g} {ff[k + '_unit']}" for k in ("kS", "kV", "kA"))
        + f" (u = kS sign(v) + kV v + kA dv/dt, v in {unit})")
    return "\n".join([text, *lines])


def in_speed_unit(est) -> dict[str, Any] | None:
    """The speed figures of ``est`` in the unit its data came in (None for rad/s): ``b/a``, ``b`` and its
    interval, the residual when it is a speed, the top speed at the input limit, kS, kV, kA (SysId's form);
    JSON ``in_speed_unit``."""
    from motorsim.units import speed_in
    unit = getattr(est, "speed_unit", "rad/s")
    if unit == "rad/s":
        return None
    ci = est.confidence_interval(0.95).get("b", (math.nan, math.nan))
    out: dict[str, Any] = {"unit": unit, "static_gain": speed_in(est.static_gain, unit), "b": speed_in(est.b, unit),
                           "b_ci95": [speed_in(float(ci[0]), unit), speed_in(float(ci[1]), unit)]}
    if est.residual_unit == "rad/s":
        out["residual_rms"] = speed_in(est.residual_rms, unit)
    if est.input_limit is not None:
        out["top_speed"] = speed_in(abs(est.static_gain) * est.input_limit, unit)
    out["feedforward"] = _feedforward_in(est, unit)
    return out


def _feedforward_in(est, unit: str) -> dict[str, Any]:
    """kS, kV, kA with their 95 % intervals per ``unit`` (SysId's form: V per rotation/s for a log in rev/s)."""
    from identify.feedforward import feedforward_constants
    from motorsim.units import SPEED_UNITS
    ff = feedforward_constants(est)
    ci = ff.confidence_interval(0.95)
    per = SPEED_UNITS[unit]                    # rad/s per unit: a constant per rad/s times this is per unit
    u = est.input_unit
    acceleration = f"{unit}/s" if unit == "rpm" else unit.replace("/s", "/s^2")
    out: dict[str, Any] = {}
    for key, name, scale, unit_text in (("ks", "kS", 1.0, u), ("kv", "kV", per, f"{u}/({unit})"),
                                        ("ka", "kA", per, f"{u}/({acceleration})")):
        out[name] = getattr(ff, key) * scale
        out[f"{name}_ci95"] = [ci[key][0] * scale, ci[key][1] * scale]
        out[f"{name}_unit"] = unit_text
    return out


def format_validation(report, name: str) -> str:
    """Human-readable summary of a ValidationReport (its ``str``, indented under the file's name)."""
    return "\n".join([f"validation  {name}", *(f"  {line}" for line in str(report).splitlines())])
