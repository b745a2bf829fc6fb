"""``motorid frequency``: the frequency response of recordings, models overlaid, distortion when it can tell.

The computations are :func:`identify.frequency_estimate.frequency_response` and, for odd-multisine
runs, :func:`identify.best_linear.best_linear_approximation`; this module is their command line.
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

__all__ = ["add_frequency_arguments", "run_frequency", "format_frequency_table"]


def add_frequency_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid frequency``."""
    from identify.frequency_estimate import ESTIMATORS
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


def _distortion(recs) -> Any:
    """The BLA of odd-multisine runs (None for any other input)."""
    from identify.best_linear import best_linear_approximation
    from identify.frequency_estimate import excitation_of
    from motorsim.excitation import OddMultisine
    if not all(isinstance(excitation_of(r), OddMultisine) for r in recs):
        return None
    return best_linear_approximation(recs)


def run_frequency(args: argparse.Namespace) -> int:
    """Estimate, print the table (and the distortion summary), write the Bode plot if asked."""
    from identify.errors import NotIdentifiableError
    from identify.frequency_estimate import frequency_response
    say = print_to_stderr if args.json else print
    recs = read_inputs(args.files, args)
    try:
        frf = frequency_response(recs, method=args.method, segment=args.segment)
        distortion = _distortion(recs) if args.method in ("auto", "periodic") else None
    except NotIdentifiableError as exc:
        raise CommandError(str(exc)) from exc
    if distortion is not None and distortion.realisations >= 2:
        frf = distortion.frequency_response   # the BLA: its bound holds the nonlinear distortion too
    models = _models(args.model, frf)
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
               "distortion": None if distortion is None else distortion.to_dict()}
        print(json.dumps(doc))
    return 0
