"""``motorid frequency``: the frequency response of recordings, models overlaid, distortion when it can tell.

The computations are :func:`identify.frequency.frequency_estimate.frequency_response` and, for odd-multisine
runs, :func:`identify.frequency.best_linear.best_linear_approximation`; this module is their command line.
"""
from __future__ import annotations

import argparse
import json
import math
from typing import Any

import numpy as np

from motorid.arguments import CommandError, print_to_stderr
from motorid.commands.identify import read_inputs
from motorid.commands.importing import add_column_arguments

__all__ = ["add_frequency_arguments", "run_frequency", "format_frequency_table", "FIT_STRUCTURES"]

#: The structures ``--structure`` fits (those with a frequency response of their own).
FIT_STRUCTURES = ("linear", "second-order")


def add_frequency_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid frequency``."""
    from identify.frequency.frequency_estimate import ESTIMATORS
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="recordings (format v1), or foreign files with the column flags; several are pooled "
                             "(one run per frequency, realisations of an odd multisine)")
    parser.add_argument("--model", action="append", default=[], metavar="MODEL.json",
                        help="a model saved by 'motorid identify --save', overlaid with its uncertainty band "
                             "(repeat for several)")
    parser.add_argument("--plot", metavar="FILE.png", help="Bode plot: data with its bounds and coherence, models")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON document on stdout (the human-readable text goes to stderr)")
    parser.add_argument("--method", default="auto", choices=ESTIMATORS,
                        help="estimator: periodic (odd multisine, PRBS periods), sines (sine fit), welch "
                             "(broadband); default auto, from the recorded excitation")
    parser.add_argument("--segment", type=int, default=None, metavar="N",
                        help="welch's segment length in samples (default about a sixteenth of the run)")
    parser.add_argument("--level", type=float, default=0.95,
                        help="confidence level of the bounds, a probability (default 0.95)")
    parser.add_argument("--structure", default=None, choices=FIT_STRUCTURES,
                        help="also fit this model structure to the response, weighted by its bounds, print its "
                             "parameters with standard errors and overlay it: linear b/(s+a), second-order "
                             "b/((s+a)(tau_e s+1)) (default: no fit)")
    parser.add_argument("--input-delay", dest="input_delay", type=int, default=0, metavar="N",
                        help="whole samples of input delay in the --structure fit (default 0)")
    add_column_arguments(parser, required=False)


def format_frequency_table(frf, models=(), level: float = 0.95) -> str:
    """Frequency, gain, phase, their bounds and the coherence per line; models' gains beside."""
    low, high = frf.gain_bounds_db(level)
    half = frf.phase_bounds_deg(level)
    names = "".join(f" {m.name[:12]:>12}" for m in models)
    head = (f"{'omega':>9} {'f [Hz]':>8} {'gain dB':>8} {'low':>7} {'high':>7} {'phase':>8} {'+-':>6} "
            f"{'coher':>6}{names}")
    lines = [head, "-" * len(head)]
    outside = [~frf.covers(m.response, level) for m in models]
    for i, w in enumerate(frf.omega):
        cells = "".join(f" {20 * math.log10(abs(m.response[i])):>11.2f}{'*' if out[i] else ' '}"
                        for m, out in zip(models, outside))
        lo = f"{low[i]:>7.2f}" if math.isfinite(low[i]) else f"{'-inf':>7}"
        lines.append(f"{w:>9.4g} {w / (2 * math.pi):>8.4g} {frf.gain_db()[i]:>8.2f} {lo} {high[i]:>7.2f} "
                     f"{frf.phase_deg()[i]:>8.2f} {half[i]:>6.2f} {frf.coherence[i]:>6.3f}{cells}")
    return "\n".join(lines)


def _models(paths: list[str], frf) -> list:
    from motorid.commands.control import load_model_file
    models = []
    for path in paths:
        est = load_model_file(path)
        if not math.isclose(est.sample_period, frf.sample_period, rel_tol=1e-6):
            raise CommandError(f"--model {path}: sample period {est.sample_period!r} s differs from the data's "
                               f"{frf.sample_period!r} s")
        models.append(frf.model_of(est, name=est.method))
    return models


def _fit(args: argparse.Namespace, frf) -> Any:
    """The ``--structure`` fit to ``frf`` (:func:`identify.fit_frequency_response`), None without the flag."""
    from identify.errors import NotIdentifiableError
    from identify.frequency.frequency_fit import fit_frequency_response
    if args.input_delay != 0 and args.structure is None:
        raise CommandError(f"--input-delay {args.input_delay} applies to the --structure fit: give --structure")
    if not 0 <= args.input_delay <= 1000:
        raise CommandError(f"--input-delay must be 0...1000 samples, got {args.input_delay!r}")
    if args.structure is None:
        return None
    try:
        return fit_frequency_response(frf, input_delay=args.input_delay, structure=args.structure)
    except NotIdentifiableError as exc:
        raise CommandError(f"--structure {args.structure}: {exc}") from exc


def _describe_fit(estimate, structure: str) -> str:
    """The fit's parameters with standard errors, and how well it fits within the bounds."""
    se, units = estimate.stderr(), estimate.model_structure().units(estimate.input_unit)
    values = estimate.values()
    parts = [f"{n} = {values[n]:.6g} +- {se[n]:.2g} {units.get(n, '')}".rstrip() for n in estimate.param_names]
    delay = f", input delay {estimate.input_delay} samples" if estimate.input_delay else ""
    return (f"fit {structure}: {', '.join(parts)}{delay}; standardised residual RMS {estimate.residual_rms:.3g} "
            f"(about 1 within the bounds), fit {estimate.fit_percent:.2f} %")


def _distortion(recs) -> Any:
    """The BLA of odd-multisine runs (None for any other input)."""
    from identify.frequency.best_linear import best_linear_approximation
    from identify.frequency.frequency_estimate import excitation_of
    from motorsim.excitation import OddMultisine
    if not all(isinstance(excitation_of(r), OddMultisine) for r in recs):
        return None
    return best_linear_approximation(recs)


#: The confidence levels ``--level`` takes.
LEVEL_RANGE = (0.5, 1 - 1e-9)


def run_frequency(args: argparse.Namespace) -> int:
    """Estimate, print the table (and the distortion summary), write the Bode plot if asked."""
    from identify.errors import NotIdentifiableError
    from identify.frequency.frequency_estimate import frequency_response
    say = print_to_stderr if args.json else print
    if not (math.isfinite(args.level) and LEVEL_RANGE[0] <= args.level <= LEVEL_RANGE[1]):
        raise CommandError(f"--level must be a probability in {LEVEL_RANGE[0]:g}...{LEVEL_RANGE[1]:g}, got "
                           f"{args.level!r}: below one half a bound holds the response less often than not, and "
                           "at 1 it is infinite")
    recs = read_inputs(args.files, args)
    try:
        frf = frequency_response(recs, method=args.method, segment=args.segment)
        distortion = _distortion(recs) if args.method in ("auto", "periodic") else None
    except NotIdentifiableError as exc:
        raise CommandError(str(exc)) from exc
    if distortion is not None and distortion.realisations >= 2:
        frf = distortion.frequency_response   # the BLA: its bound holds the nonlinear distortion too
    models = _models(args.model, frf)
    fitted = _fit(args, frf)
    if fitted is not None:
        models.append(frf.model_of(fitted, name=f"{args.structure}"))
    output = {"angle": "interval-mean speed from the angle", "speed": "the speed column"}[frf.output]
    source = "duty" if frf.input_unit == "duty" else f"input ({frf.input_unit})"
    say(f"frequency response {source} -> speed ({output}), {frf.method}, {len(frf)} lines, "
        f"{100 * args.level:g} % bounds" + (f", resolution {frf.resolution:.3g} rad/s" if frf.resolution else ""))
    say(format_frequency_table(frf, models, args.level))
    for m in models:
        out = frf.departures(m, args.level)
        where = ", ".join(f"{w:.3g}" for w in out[:12]) + (" ..." if len(out) > 12 else "")
        say(f"model {m.name}: " + (f"outside the data's bound at {len(out)} of {len(frf)} lines ({where} rad/s)"
                                   if len(out) else "within the data's bound at every line"))
    if fitted is not None:
        say(_describe_fit(fitted, args.structure))
    if distortion is not None:
        say(f"distortion  {distortion.summary()}")
    if args.plot:
        from motorid.plots import plot_bode
        plot_bode(frf, models, args.plot, level=args.level, distortion=distortion,
                  title=f"frequency response of {', '.join(args.files)[:80]}")
        say(f"plot        {args.plot}")
    if args.json:
        doc = {"frequency_response": frf.to_dict(args.level),
               "models": [{"name": m.name, "gain_db": (20 * np.log10(np.abs(m.response))).tolist(),
                           "outside": frf.departures(m, args.level).tolist()} for m in models],
               "distortion": None if distortion is None else distortion.to_dict(),
               "fit": None if fitted is None else fitted.to_dict()}
        print(json.dumps(doc))
    return 0
