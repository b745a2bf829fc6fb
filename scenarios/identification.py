"""``motorid identify``: fit a and b to recordings, optionally validate on a held-out run."""
from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np

from motorsim.recording import read_recording

from .arguments import CommandError

__all__ = ["add_identify_arguments", "run_identify", "estimator_options", "format_estimate", "format_validation"]

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
    parser.add_argument("files", nargs="+", metavar="FILE", help="recordings (format v1); several are pooled")
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=available_methods(),
                        help=f"estimator (default {DEFAULT_METHOD}, the most accurate available)")
    parser.add_argument("--input-delay", type=_input_delay, default=None, metavar="auto|N",
                        help="input delay in samples, or 'auto' to estimate it (oe, iv, oe-friction; default auto "
                             "for them: one fit per candidate delay 0-10)")
    parser.add_argument("--fix-bias", action="store_true",
                        help="oe-friction: hold the constant acceleration (bias, rad/s^2) at 0")
    parser.add_argument("--validate", metavar="TEST", help="held-out recording: NRMSE fit and residual tests")
    parser.add_argument("--report", metavar="FILE.png",
                        help="figure: measured vs model speed, residual autocorrelation and cross-correlation "
                             "(on TEST, else on the first FILE)")
    parser.add_argument("--json", action="store_true", help="end the output with one JSON line")


def estimator_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword options the flags give the estimator; a flag the method does not take is an error."""
    from identify.methods import method_options
    accepted = method_options(args.method)
    options = {}
    for flag, (name, unset) in _OPTION_FLAGS.items():
        value = getattr(args, name)
        if value is unset and name == "input_delay" and name in accepted:
            value = "auto"          # the default: a missed delay biases a fit by far more than it costs
        if value is unset:
            continue
        if name not in accepted:
            raise CommandError(f"{flag} is not supported by method {args.method!r}")
        options[name] = value
    return options


def run_identify(args: argparse.Namespace) -> int:
    """Fit, print the estimate (and the validation), write the report figure if asked."""
    from identify import fit, validate
    from identify.estimate import json_ready
    recs = [read_recording(f) for f in args.files]
    options = estimator_options(args)
    est = fit(recs, method=args.method, **options)
    print(format_estimate(est))
    if options.get("input_delay") == "auto":
        print(f"delay       {int(est.extra['input_delay'])} samples, chosen by the least output error over 0-10 "
              "(--input-delay N fixes it)")
    out = est.to_dict()
    report = None
    if args.validate:
        report = validate(est, read_recording(args.validate))
        print(format_validation(report, args.validate))
        out.update(report.summary())
    if args.report:
        from .plots import plot_validation
        if report is None:
            report = validate(est, recs[0])
        where = args.validate or args.files[0]
        path = plot_validation(report, est, args.report, title=f"{est.method} on {where}")
        print(f"report      {path}")
    if args.json:
        print(json.dumps(json_ready(out)))
    return 0


def format_estimate(est) -> str:
    """Human-readable summary of an Estimate (value, standard error, 95 % interval)."""
    se = est.stderr()
    ci = est.confidence_interval(0.95)

    def ci_text(name):
        lo, hi = ci[name]
        return f"   95 % CI [{lo:.6g}, {hi:.6g}]" if np.isfinite(lo) and np.isfinite(hi) else ""
    lines = [f"method      {est.method}",
             f"a           {est.a:.6g} 1/s   (stderr {se['a']:.2g}){ci_text('a')}",
             f"b           {est.b:.6g} (rad/s^2)/{est.input_unit}   (stderr {se['b']:.2g}){ci_text('b')}"]
    for k, v in est.extra.items():
        lines.append(f"{k:<11} {v:.6g}" + (f"   (stderr {se[k]:.2g}){ci_text(k)}" if k in se else ""))
    lines += [f"b/a         {est.static_gain:.6g} (rad/s)/{est.input_unit}",
              f"fit         {est.fit_percent:.2f} % (NRMSE, simulated vs measured speed)",
              f"residual    {est.residual_rms:.3g} {est.residual_unit} RMS",
              f"samples     {est.n_samples}"]
    return "\n".join(lines)


def format_validation(report, name: str) -> str:
    """Human-readable summary of a ValidationReport."""
    white = "white" if report.is_white() else "NOT white (model misses dynamics or friction)"
    indep = "independent of the input" if report.independence_p >= 0.05 else "CORRELATED with the input"
    return "\n".join([
        f"validation  {name}",
        f"  fit       {report.fit_percent:.2f} % (NRMSE, held-out speed; {report.initial_state})",
        f"  residual  {white}: Ljung-Box p = {report.whiteness_p:.3g}, "
        f"{100 * report.share_outside_band:.0f} % of lags outside +-{report.band:.3g}",
        f"  residual  {indep}: p = {report.independence_p:.3g}"])
