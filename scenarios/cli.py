"""The ``motorid`` command line.

Each sub-command NAME lives in a module with ``add_NAME_arguments(parser)`` and
``run_NAME(args) -> int``; ``_COMMANDS`` maps the name to that module.  Modules
import heavy dependencies (matplotlib) inside ``run_NAME`` only.
Add a command by adding one line to ``_COMMANDS``.

Errors a user can fix (bad flags, bad files, data that cannot identify the
motor) print ``motorid: error: ...`` and exit with status 2, never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import json
import sys
from typing import Sequence

import numpy as np

from motorsim.excitation import parse_excitation
from motorsim.plant import Motor
from motorsim.recording import RecordingFormatError, read_recording, write_recording
from motorsim.rig import Experiment, SimRig
from motorsim.sensors import DEFAULT_COUNTS_PER_REV, Encoder

__all__ = ["main", "add_experiment_arguments", "experiment_from_args", "add_bench_arguments",
           "sim_rig_from_args", "CommandError"]

#: name -> (module, one-line help); the module has ``add_<name>_arguments(parser)`` and
#: ``run_<name>(args) -> int`` (``-`` in the name becomes ``_``).
_COMMANDS = {
    "simulate": ("scenarios.cli", "simulate the bench and write a recording (format v1)"),
    "identify": ("scenarios.cli", "identify a and b from recordings"),
    "demo": ("scenarios.demo", "the article's section 5 on the simulated bench"),
    "bench": ("scenarios.bench", "speed and accuracy benchmarks"),
    "sweep": ("scenarios.sweep", "sweep scenarios: grid x estimators x Monte Carlo repetitions"),
    "design": ("scenarios.design", "recommend the sine that minimises the Cramér-Rao bound of a and b"),
    "live": ("scenarios.live", "run an experiment on the bench (or 'fake://'), record it live, identify"),
}


class CommandError(Exception):
    """A user-facing error: printed as ``motorid: error: ...``, exit status 2."""


_EXCITATION_FLAGS = {
    "sine": "FREQ[,AMP[,PHASE]]: the article's A sin(omega t + alpha), omega in rad/s (AMP default 200)",
    "multisine": "F,A,P;F,A,P...: up to 4 sines",
    "chirp": "F0,F1[,AMP]: linear chirp from F0 to F1 rad/s",
    "prbs": "HIGH,LOW[,ORDER[,HOLD[,SEED]]]: maximal-length PRBS, each bit held HOLD samples",
    "step": "AFTER[,AT_TIME[,BEFORE]]: step of the duty at AT_TIME s",
    "constant": "LEVEL: constant duty",
}


def add_experiment_arguments(parser: argparse.ArgumentParser, *, sample_period: float = 0.005,
                             duration: float = 10.0) -> None:
    """Flags that define an :class:`~motorsim.rig.Experiment` (shared by ``simulate`` and ``live``)."""
    g = parser.add_argument_group("experiment")
    g.add_argument("--sample-period", type=float, default=sample_period, metavar="S",
                   help=f"sample period in s (default {sample_period})")
    g.add_argument("--duration", type=float, default=duration, metavar="T",
                   help=f"length of the run in s (default {duration})")
    g.add_argument("--duty-limit", type=int, default=255, metavar="N", help="duty clamp (default 255)")
    ex = g.add_mutually_exclusive_group()
    for name, help_ in _EXCITATION_FLAGS.items():
        ex.add_argument(f"--{name}", metavar="ARGS", help=help_)
    ex.add_argument("--excitation", metavar="KIND:ARGS", help="any excitation as KIND:ARGS, e.g. sine:10,200")


def experiment_from_args(args: argparse.Namespace) -> Experiment:
    """Build the Experiment the flags describe (default: the article's 200 sin(10 t))."""
    spec = args.excitation
    for name in _EXCITATION_FLAGS:
        if getattr(args, name, None):
            spec = f"{name}:{getattr(args, name)}"
    spec = spec or "sine:10,200,0"
    return Experiment(parse_excitation(spec), sample_period=args.sample_period, duration=args.duration,
                      duty_limit=args.duty_limit)


def add_bench_arguments(parser: argparse.ArgumentParser, *, a: float | None = None, b: float | None = None) -> None:
    """Flags that define the simulated motor and encoder (``simulate``, ``demo``)."""
    g = parser.add_argument_group("simulated bench")
    g.add_argument("--a", type=float, required=a is None, default=a, help="true pole a in 1/s"
                   + (f" (default {a})" if a is not None else ""))
    g.add_argument("--b", type=float, required=b is None, default=b, help="true gain b in (rad/s^2)/duty"
                   + (f" (default {b})" if b is not None else ""))
    g.add_argument("--counts-per-rev", type=int, default=DEFAULT_COUNTS_PER_REV, metavar="N",
                   help=f"encoder counts per revolution (default {DEFAULT_COUNTS_PER_REV})")
    g.add_argument("--angle-noise", type=float, default=0.0, metavar="RAD",
                   help="std of Gaussian angle noise before the encoder floors it, rad (default 0)")
    g.add_argument("--jitter", type=float, default=0.0, help="timing jitter, fraction of the sample period (default 0)")
    g.add_argument("--drop-rate", type=float, default=0.0, help="probability a sample is lost (default 0)")
    g.add_argument("--friction", type=float, default=0.0, help="Coulomb friction c in rad/s^2 (default 0)")
    g.add_argument("--bias", type=float, default=0.0, help="constant acceleration d in rad/s^2 (default 0)")
    g.add_argument("--dead-zone", type=float, default=0.0, help="duty dead zone (default 0)")
    g.add_argument("--input-delay", type=int, default=0, metavar="SAMPLES", help="input delay in samples (default 0)")
    g.add_argument("--seed", type=int, default=0, help="seed of the noise, jitter and drops (default 0)")
    g.add_argument("--record-speed", action="store_true",
                   help="also record the true speed (an ideal tachometer) in a speed_rad_s column")


def sim_rig_from_args(args: argparse.Namespace) -> SimRig:
    """The SimRig the bench flags describe."""
    motor = Motor(args.a, args.b, friction=args.friction, bias=args.bias, dead_zone=args.dead_zone,
                  input_delay=args.input_delay)
    encoder = Encoder(args.counts_per_rev, angle_noise=args.angle_noise)
    return SimRig(motor, encoder, jitter=args.jitter, drop_rate=args.drop_rate,
                  record_speed=args.record_speed, rng=np.random.default_rng(args.seed))


def add_simulate_arguments(parser: argparse.ArgumentParser) -> None:
    add_bench_arguments(parser)
    add_experiment_arguments(parser)
    parser.add_argument("--out", required=True, metavar="FILE.csv", help="where to write the recording")


def run_simulate(args: argparse.Namespace) -> int:
    rec = sim_rig_from_args(args).run(experiment_from_args(args))
    path = write_recording(rec, args.out)
    print(f"wrote {len(rec)} samples ({rec.metadata['excitation']}) to {path}")
    return 0


def add_identify_arguments(parser: argparse.ArgumentParser) -> None:
    from identify import DEFAULT_METHOD, available_methods
    parser.add_argument("files", nargs="+", metavar="FILE", help="recordings (format v1); several are pooled")
    parser.add_argument("--method", default=DEFAULT_METHOD, choices=available_methods(),
                        help=f"estimator (default {DEFAULT_METHOD}, the most accurate available)")
    parser.add_argument("--delay", type=_delay, default=None, metavar="auto|N",
                        help="input delay in samples, or 'auto' to estimate it (oe, iv, oe-friction)")
    parser.add_argument("--fix-d", action="store_true", help="oe-friction: hold the offset d at 0")
    parser.add_argument("--validate", metavar="TEST", help="held-out recording: NRMSE fit and residual tests")
    parser.add_argument("--report", metavar="FILE.png",
                        help="figure: measured vs model speed, residual autocorrelation and cross-correlation "
                             "(on TEST, else on the first FILE)")
    parser.add_argument("--json", action="store_true", help="end the output with one JSON line")


def _delay(text: str):
    if text == "auto":
        return "auto"
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--delay must be 'auto' or an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"--delay must be 'auto' or an integer >= 0, got {text!r}")
    return value


def run_identify(args: argparse.Namespace) -> int:
    import inspect

    from identify import fit, validate
    from identify.estimate import json_ready
    from identify.methods import method_function
    recs = [read_recording(f) for f in args.files]
    accepted = inspect.signature(method_function(args.method)).parameters
    options = {}
    for flag, name, value, unset in (("--delay", "input_delay", args.delay, None),
                                     ("--fix-d", "fix_bias", args.fix_d, False)):
        if value is not unset:
            if name not in accepted:
                raise CommandError(f"{flag} is not supported by method {args.method!r}")
            options[name] = value
    est = fit(recs, method=args.method, **options)
    print(format_estimate(est))
    out = est.to_dict()
    report = None
    if args.validate:
        report = validate(est, read_recording(args.validate))
        print(format_validation(report, args.validate))
        out.update(report.summary())
    if args.report:
        from scenarios.plots import plot_validation
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
        f"  fit       {report.fit_percent:.2f} % (NRMSE, held-out speed, initial state fitted)",
        f"  residual  {white}: Ljung-Box p = {report.whiteness_p:.3g}, "
        f"{100 * report.share_outside_band:.0f} % of lags outside +-{report.band:.3g}",
        f"  residual  {indep}: p = {report.independence_p:.3g}"])


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="motorid", description="Identify a and b of a PWM-driven DC motor, "
                                     "dω/dt + aω = b·u, on a simulated or real bench.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, help_) in _COMMANDS.items():
        p = sub.add_parser(name, help=help_, description=help_)
        _command(name, "add", "arguments")(p)
        p.set_defaults(_run=_command(name, "run"))
    return parser


def _command(name: str, prefix: str, suffix: str = ""):
    module = importlib.import_module(_COMMANDS[name][0])
    attr = "_".join(x for x in (prefix, name.replace("-", "_"), suffix) if x)
    return getattr(module, attr)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``motorid`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args._run(args)
    except (CommandError, RecordingFormatError, ValueError, TypeError) as exc:
        print(f"motorid: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("motorid: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
