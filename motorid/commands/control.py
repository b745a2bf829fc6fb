"""``motorid control design``: a controller from a model, its gains and predicted response; the closed-loop runs.

The controller flags (``--controller``, ``--duty-weight``, ``--integral-weight``, ``--time-constant``,
``--min-phase-margin``, ``--feedforward``, ``--derivative``, ``--reference``) are shared by
``motorid control design`` and ``motorid simulate``; the design model comes from ``--a/--b`` (with ``--friction``,
``--bias``, ``--input-delay``) or from a saved estimate (``--model FILE``).
:func:`compare_designs` is the closed-loop part of ``motorid demo``: the same controller
designed from several estimates, run on one simulated bench.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import re
import warnings
from typing import Any, Sequence

import numpy as np

from motorid.arguments import CommandError, print_to_stderr
from motorid.arguments import _seed as seed_flag
from motorid.ranges import check_design_model, check_reference_times, check_run_length
from motorsim.control import (
    CONTROLLERS,
    INTEGRAL_WEIGHT,
    MIN_PHASE_MARGIN,
    ClosedLoopExperiment,
    Controller,
    PlantModel,
    Prediction,
    Reference,
    design_controller,
    parse_reference,
    settings_from,
    tracking_error,
)
from motorsim.excitation import DUTY_LIMIT
from motorsim.plant import Motor
from motorsim.recording import Recording
from motorsim.rig import Rig
from motorsim.sensors import DEFAULT_COUNTS_PER_REV

__all__ = ["add_controller_arguments", "add_model_arguments", "controller_from_args", "model_from_args",
           "load_model_file", "closed_loop_from_args", "require_duty_model", "reference_in_si", "default_reference",
           "reference_from_args", "refuse_controller_flags",
           "ClosedLoopRow", "compare_designs", "format_closed_loop_table", "add_control_arguments", "run_control"]

#: The input limit of a model in % that states none: the whole of the scale.
PERCENT_LIMIT = 100.0
#: The reference when the model's top speed is unknown (an input in V or % without an input limit), and
#: of position controllers: rad/s or rad.
DEFAULT_REFERENCE = "sine:10,10"
#: Flags of :func:`add_controller_arguments` that only a controller uses (their ``dest``).
CONTROLLER_FLAGS = ("reference", "model", "duty_weight", "time_constant", "integral_weight", "min_phase_margin",
                    "feedforward", "derivative")
#: Flags of :func:`add_model_arguments` (their ``dest``): the model a controller is designed from.
MODEL_FLAGS = ("a", "b", "friction", "bias", "input_delay", "electrical_time_constant")
#: Units a reference's levels may carry (``step:1500rpm``), per quantity the controller tracks.
REFERENCE_UNITS = {"speed": ("rad/s", "deg/s", "rpm", "rev/s"), "angle": ("rad", "deg", "rev")}
_UNIT_NUMBER = re.compile(r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(rad/s|deg/s|rev/s|rpm|rad|deg|rev)(?![\w/])")


def add_controller_arguments(parser: argparse.ArgumentParser, *, required: bool = False) -> None:
    """Flags choosing and tuning a controller, and its reference."""
    g = parser.add_argument_group("controller")
    g.add_argument("--controller", choices=list(CONTROLLERS), required=required,
                   help="mpc (one-step model predictive), pi (speed), position (P/PD on the counts), "
                        "feedforward (speed, from the model alone), lqr (speed LQR, input delay in the state), "
                        "lqr-integral (speed LQR with the integral of the speed error in the state: no steady "
                        "error under a bias, friction or gain the model lacks), lqr-position (position LQR)")
    g.add_argument("--duty-weight", dest="duty_weight", type=float, default=None, metavar="LAMBDA",
                   help="mpc, lqr, lqr-integral: weight lambda of u^2 in (rad/s)^2 per duty^2 (default 1e-4, "
                        "the LQRs 1e-3); "
                        "lqr-position: in rad^2 per duty^2 (default 1e-6)")
    g.add_argument("--time-constant", dest="time_constant", type=float, default=None, metavar="S",
                   help="pi, position: closed-loop time constant in s (default 0.05)")
    g.add_argument("--integral-weight", dest="integral_weight", type=float, default=None, metavar="W",
                   help="lqr-integral: weight of the squared integral of the speed error (an angle, rad) in "
                        f"(rad/s)^2 per rad^2, 1/s^2 (default {INTEGRAL_WEIGHT:g}: 0.1 rad weighs as 1 rad/s)")
    g.add_argument("--min-phase-margin", dest="min_phase_margin", type=float, default=None, metavar="DEG",
                   help="pi, position: the least phase margin in degrees of the loop on the model, input delay "
                        "included; a --time-constant too short for it is lengthened to the shortest that keeps "
                        f"it, with a warning (default {MIN_PHASE_MARGIN:g}, 0 keeps the time constant asked for)")
    g.add_argument("--feedforward", action="store_true", default=None,
                   help="pi: add the model's feedforward to the PI output")
    g.add_argument("--derivative", choices=("true", "false"), default=None,
                   help="position: use the speed term (PD, default true) or not (P)")
    g.add_argument("--reference", default=None, metavar="KIND:ARGS",
                   help="what to track: constant:LEVEL, step:AFTER[,AT_TIME[,BEFORE]], sine:FREQ,AMP[,PHASE][@OFFSET], "
                        "multisine:F,A,P;..., trapezoid:LEVEL,RAMP_TIME,HOLD_TIME[,AT_TIME]; levels in rad/s "
                        "(speed) or rad (position), or with a unit: step:1500rpm, sine:10,5rev/s, step:90deg "
                        "(default for speed: a sine at min(10 rad/s, a) with a third of the model's top speed, "
                        f"b/a x input limit, in the model's speed unit; else {DEFAULT_REFERENCE})")
    g.add_argument("--model", default=None, metavar="FILE.json",
                   help="design from this saved estimate instead of --a/--b")


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of the design model: ``--a``, ``--b``, ``--friction``, ``--bias``, ``--input-delay``,
    ``--electrical-time-constant``."""
    m = parser.add_argument_group("model (what the controller is designed from)")
    m.add_argument("--a", type=float, default=None, help="pole a in 1/s (or --model)")
    m.add_argument("--b", type=float, default=None, help="gain b in (rad/s^2)/duty (or --model)")
    m.add_argument("--friction", type=float, default=None, help="Coulomb friction c in rad/s^2 (default 0)")
    m.add_argument("--bias", type=float, default=None, help="constant acceleration d in rad/s^2 (default 0)")
    m.add_argument("--input-delay", dest="input_delay", type=int, default=None,
                   help="input delay in samples (default 0)")
    m.add_argument("--electrical-time-constant", dest="electrical_time_constant", type=float, default=None,
                   metavar="S", help="time constant tau_e in s of a lag between the duty and the torque, the "
                                     "model b/((s+a)(tau_e s+1)) (default 0: none)")
    parser.set_defaults(design_model_flags=True)     # these flags describe the design model, as --model does


def refuse_controller_flags(args: argparse.Namespace, *, model_flags: bool = False) -> None:
    """Refuse the controller's flags given without ``--controller``: the run is open loop and they would do nothing.

    Parameters
    ----------
    args : argparse.Namespace
        Parsed flags of a command with :func:`add_controller_arguments`.
    model_flags : bool
        The command's ``--a/--b``, ``--friction``, ``--bias``, ``--input-delay`` are
        :func:`add_model_arguments`' (the design model), not the bench's (default False).
    """
    if getattr(args, "controller", None):
        return
    given = [name for name in CONTROLLER_FLAGS + (MODEL_FLAGS if model_flags else ())
             if getattr(args, name, None) is not None]
    if given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise CommandError(f"{flags} {'applies' if len(given) == 1 else 'apply'} only with --controller: without "
                           "it the run is open loop (the excitation); give --controller KIND, or leave "
                           f"{'it' if len(given) == 1 else 'them'} out")


def closed_loop_from_args(args: argparse.Namespace, sample_period: float, counts_per_rev: int, *,
                          rig_input_delay: int = 0) -> ClosedLoopExperiment:
    """The closed-loop run the flags describe: ``--controller`` designed from the model flags, ``--reference``.

    ``rig_input_delay`` is the delay the rig adds between a computed duty and its application (the
    device's one sample): a model with less is designed with the rig's, and a note says so.
    """
    if not args.model and (args.a is None or args.b is None):
        raise CommandError("give the model the controller is designed from: --a and --b, or --model FILE.json")
    args.sample_period, args.counts_per_rev = sample_period, counts_per_rev
    require_duty_model(args)
    model = model_from_args(args)
    if model.input_delay < rig_input_delay:
        print_to_stderr(f"note: the device applies each duty {rig_input_delay} sample(s) after computing it; "
                        f"the controller is designed with input delay {rig_input_delay} (the model had "
                        f"{model.input_delay})")
        model = model.with_values(input_delay=rig_input_delay)
    controller = controller_from_args(args, model)
    speed_unit = load_model_file(args.model).speed_unit if args.model else "rad/s"
    reference = reference_from_args(args, controller, speed_unit, float(args.duty_limit))
    return ClosedLoopExperiment(controller, reference, args.duration, args.duty_limit)


def reference_in_si(spec: str, quantity: str = "speed") -> str:
    """``spec`` with every level that carries a unit (``1500rpm``, ``90deg``) in rad/s or rad.

    Examples
    --------
    >>> reference_in_si("step:1500rpm,0.5")
    'step:157.07963267948966,0.5'
    """
    from motorsim.units import ANGLE_UNITS, SPEED_UNITS
    factors = {**SPEED_UNITS, **{u: f for u, f in ANGLE_UNITS.items() if u != "counts"}}

    def convert(match: re.Match) -> str:
        unit = match.group(2)
        if unit not in REFERENCE_UNITS[quantity]:
            other = "position" if quantity == "speed" else "speed"
            raise CommandError(f"--reference {spec!r}: {match.group(0)!r} is a {other}, but this controller tracks "
                               f"a {quantity}: use one of {', '.join(REFERENCE_UNITS[quantity])}")
        return repr(float(match.group(1)) * factors[unit])
    return _UNIT_NUMBER.sub(convert, spec)


def default_reference(model: PlantModel, speed_unit: str, input_limit: float | None) -> tuple[str, str]:
    """The speed reference in the model's own range and unit, and why: a sine at ``min(10 rad/s, a)`` whose
    amplitude is a third of the top speed ``b/a x input_limit`` (2 significant figures in ``speed_unit``);
    :data:`DEFAULT_REFERENCE` when the input limit is unknown.

    Examples
    --------
    >>> default_reference(PlantModel(25.0, 3.0, 0.005, 16667), "rad/s", 255.0)[0]
    'sine:10,10rad/s'
    """
    from motorsim.units import speed_in
    if input_limit is None:
        return DEFAULT_REFERENCE, "the model's top speed is unknown (no input limit)"
    top = speed_in(abs(model.b / model.a) * input_limit, speed_unit)
    amplitude = float(f"{top / 3:.2g}")
    frequency = float(f"{min(10.0, model.a):.2g}")
    return (f"sine:{frequency:g},{amplitude:g}{speed_unit}",
            f"a third of the model's top speed {top:.4g} {speed_unit} (b/a x input limit), at min(10 rad/s, a)")


def reference_from_args(args: argparse.Namespace, controller: Controller, speed_unit: str,
                        input_limit: float | None) -> Reference:
    """``--reference`` (units converted), else :func:`default_reference` for a speed controller, said on stderr."""
    spec = args.reference
    if spec is None:
        if controller.reference_unit != "rad/s":
            spec = DEFAULT_REFERENCE
        else:
            spec, why = default_reference(controller.model, speed_unit, input_limit)
            print_to_stderr(f"motorid: note: --reference {spec} ({why}; give --reference to choose)")
        args.reference = spec
    quantity = "speed" if controller.reference_unit == "rad/s" else "angle"
    try:
        reference = parse_reference(reference_in_si(spec, quantity))
    except ValueError as exc:
        raise CommandError(f"--reference: {exc}") from None
    return check_reference_times(reference, controller.model.sample_period)


def load_model_file(path: str) -> Any:
    """The estimate saved in ``path`` by ``motorid identify --save`` (``Estimate.from_json``)."""
    from identify.estimate import MAX_ESTIMATE_BYTES, Estimate
    from motorsim.files import read_input_bytes
    try:
        data = read_input_bytes(path, what="--model", max_bytes=MAX_ESTIMATE_BYTES)
    except OSError as exc:
        raise CommandError(str(exc) if exc.strerror is None else f"--model {path}: cannot read: {exc.strerror}") \
            from None
    try:
        return Estimate.from_json(data)
    except (ValueError, TypeError) as exc:
        raise CommandError(f"--model {path}: not a saved model: {exc}") from None


def require_duty_model(args: argparse.Namespace) -> None:
    """Refuse a ``--model`` whose input is not the duty for a controller that runs on a rig (it computes duty)."""
    if getattr(args, "model", None):
        unit = load_model_file(args.model).input_unit
        if unit != "duty":
            raise CommandError(f"--model {args.model}: its input is in {unit}, but a rig's controller computes "
                               "duty: fit the model to a recording whose input is the duty")


def model_from_args(args: argparse.Namespace) -> PlantModel:
    """The design model: ``--model FILE`` if given, else the motor flags; ``--sample-period``, ``--counts-per-rev``."""
    source: Any
    if getattr(args, "model", None):
        given = [name for name in MODEL_FLAGS
                 if getattr(args, "design_model_flags", False) and getattr(args, name, None) is not None]
        if given:
            flags = ", ".join("--" + name.replace("_", "-") for name in given)
            raise CommandError(f"--model {args.model} gives the design model, and {flags} would be ignored: "
                               "give one or the other")
        source = load_model_file(args.model)
    else:
        source = {"a": args.a, "b": args.b, **{k: getattr(args, k, 0) or 0 for k in ("friction", "bias",
                                                                                       "input_delay")}}
        source = PlantModel(source["a"], source["b"], args.sample_period, args.counts_per_rev,
                            friction=source["friction"], bias=source["bias"], input_delay=source["input_delay"],
                            electrical_time_constant=getattr(args, "electrical_time_constant", None) or 0.0)
    return check_design_model(PlantModel.from_source(source, args.sample_period, args.counts_per_rev),
                              f"--model {args.model}" if getattr(args, "model", None) else "--a/--b")


def controller_from_args(args: argparse.Namespace, model: PlantModel) -> Controller:
    """The controller ``--controller`` designed from ``model`` with the tuning flags given."""
    values = dict(vars(args))
    if values.get("derivative") is not None:
        values["derivative"] = values["derivative"] == "true"
    kind = args.controller
    given = {k for k in ("duty_weight", "integral_weight", "time_constant", "min_phase_margin", "feedforward",
                         "derivative") if values.get(k) is not None}
    settings = settings_from(values, kind)
    ignored = given - set(settings)
    if ignored:
        flags = ", ".join("--" + k.replace("_", "-") for k in sorted(ignored))
        raise CommandError(f"{flags} {'does' if len(ignored) == 1 else 'do'} not apply to --controller {kind}")
    controller = design_controller(kind, model, **settings)
    if kind != "feedforward" and not np.any(np.asarray(controller.laws()[1].num[0][0], dtype=float)):
        tuning = ", ".join(f"--{k.replace('_', '-')} {values[k]:g}" for k in sorted(given & {"duty_weight",
                           "integral_weight", "time_constant"}))
        raise CommandError(f"--controller {kind}: the design has no feedback, every gain on the measurement is 0 "
                           + (f"with {tuning}; give a value nearer the default"
                              if tuning else "for this model; check its a and b"))
    return controller


@dataclasses.dataclass(frozen=True)
class ClosedLoopRow:
    """One design of the closed-loop comparison: where its model came from, predicted and measured tracking."""

    design: str
    model: PlantModel
    prediction: Prediction
    recording: Recording

    @property
    def measured_rms(self) -> float:
        """RMS tracking error measured on the rig, in the reference's unit."""
        err = tracking_error(self.recording)
        return float(np.sqrt(np.mean(err ** 2)))


def compare_designs(rig: Rig, designs: Sequence[tuple[str, Any]], kind: str, reference: Reference,
                    duration: float, sample_period: float, counts_per_rev: int,
                    **settings: Any) -> list[ClosedLoopRow]:
    """Design controller ``kind`` from each ``(name, model source)``, predict, and run it on ``rig``.

    Parameters
    ----------
    rig : Rig
        The bench every design runs on.
    designs : sequence of (str, Estimate or Motor or PlantModel)
        Name of the design and what it is designed from.
    kind : str
        Controller (a key of :data:`motorsim.control.CONTROLLERS`).
    reference : Reference
        What to track.
    duration : float
        Run length in s.
    sample_period : float
        Sample period in s.
    counts_per_rev : int
        Encoder resolution.
    **settings
        The controller's knobs.
    """
    rows = []
    for name, source in designs:
        model = PlantModel.from_source(source, sample_period, counts_per_rev)
        controller = design_controller(kind, model, **settings)
        prediction = controller.predict(reference, duration)
        rec = rig.run(ClosedLoopExperiment(controller, reference, duration))
        rows.append(ClosedLoopRow(name, model, prediction, rec))
    return rows


def format_closed_loop_table(rows: Sequence[ClosedLoopRow]) -> str:
    """Design, model, predicted and measured tracking RMS, and how far the measurement is from the prediction."""
    unit = rows[0].recording.metadata.get("reference_unit", "") if rows else ""
    head = (f"{'design':<10} {'a [1/s]':>9} {'b':>8} {'predicted RMS':>14} {'measured RMS':>13} "
            f"{'meas/pred':>10}   [{unit}]")
    lines = [head, "-" * len(head)]
    for r in rows:
        pred, meas = r.prediction.tracking_rms, r.measured_rms
        ratio = meas / pred if pred > 0 else math.nan
        lines.append(f"{r.design:<10} {r.model.a:>9.4f} {r.model.b:>8.5f} {pred:>14.4f} {meas:>13.4f} {ratio:>10.3f}")
    return "\n".join(lines)


def add_control_arguments(parser: argparse.ArgumentParser) -> None:
    """Flags of ``motorid control design``: the model, the controller, the prediction."""
    sub = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    p = sub.add_parser("design", help="design a controller from a model: gains, poles, predicted response",
                       description="design a controller from a model: gains, poles, predicted response")
    add_model_arguments(p)
    m = p.add_argument_group("sampling")
    m.add_argument("--sample-period", dest="sample_period", type=float, default=None,
                   help="controller sample period in s (default: the model file's, else 0.005)")
    m.add_argument("--counts-per-rev", dest="counts_per_rev", type=int, default=None,
                   help=f"encoder counts per revolution of the rig the controller runs on (default "
                        f"{DEFAULT_COUNTS_PER_REV}, said on stderr when the model comes from a file)")
    add_controller_arguments(p, required=True)
    p.add_argument("--duration", type=float, default=2.0, help="length of the predicted response in s (default 2)")
    p.add_argument("--input-limit", dest="input_limit", type=float, default=None, metavar="LIMIT",
                   help="largest input magnitude the drive accepts, in the model's input unit (default: the "
                        "model file's input_limit; 255 for a model in duty, 100 for %%); a design that needs more "
                        "is warned of")
    p.add_argument("--plot", default=None, metavar="FILE.png", help="also plot the predicted response")
    r = p.add_argument_group("robustness (plants drawn from a --model file's covariance of a and b)")
    r.add_argument("--robust", action="store_true",
                   help="tune the design (mpc and the LQRs: --duty-weight, pi and position: "
                        "--time-constant) to the best "
                        "worst-case tracking over the drawn plants instead of the point estimate")
    r.add_argument("--repetitions", type=int, default=None, metavar="N",
                   help="plants drawn from the covariance, at most 1000 (default 100)")
    r.add_argument("--seed", type=seed_flag, default=None, help="seed of the draws, an integer >= 0 (default 0)")


def run_control(args: argparse.Namespace) -> int:
    """Print the controller's gains, closed-loop poles and predicted tracking of the reference."""
    if not args.model and (args.a is None or args.b is None):
        raise CommandError("give the model: --a and --b, or --model FILE.json")
    if not args.model and args.sample_period is None:
        args.sample_period = 0.005
    unit, limit = _input_unit_and_limit(args)
    estimate = load_model_file(args.model) if args.model else None
    speed_unit = getattr(estimate, "speed_unit", "rad/s")
    speed_sensor = estimate is not None and estimate.residual_unit == "rad/s"
    encoder_known = args.counts_per_rev is not None or not speed_sensor
    sensor = _sensor(args, estimate)
    model = model_from_args(args)
    check_run_length(args.duration, model.sample_period)
    controller = controller_from_args(args, model)
    reference = reference_from_args(args, controller, speed_unit, limit)
    covariance = _model_covariance(args)
    _check_draw_flags(args, covariance)
    robustness = None
    if args.robust:
        controller, robustness = _robust_controller(args, controller, covariance, reference)
    prediction = controller.predict(reference, args.duration)
    if not args.robust:
        controller, prediction = _within_limit(args, controller, prediction, reference, limit, unit)
    print(f"model: a = {model.a:g} 1/s, b = {model.b:g} (rad/s^2)/{unit}, friction = {model.friction:g}, "
          f"bias = {model.bias:g} rad/s^2, input delay {model.input_delay} "
          f"({model.input_delay * model.sample_period:.6g} s), "
          + (f"electrical time constant {model.electrical_time_constant:g} s, " if model.electrical_time_constant
             else "")
          + (f"static friction {model.static_friction:g} rad/s^2, " if model.static_friction else "")
          + "".join(f"{name} {value:g}, " for name, value in model.plant.values().items()    # another structure's
                    if not isinstance(model.plant, Motor) and name not in ("a", "b"))
          + (f"dead zone {model.dead_zone:g} {unit} (not compensated: the design and its prediction are on the "
             "linear part), " if model.dead_zone else "") + f"dt = {model.sample_period:g} s, "
          f"{sensor}" + ("" if limit is None else f", input limit +-{limit:g} {unit}"))
    if speed_unit != "rad/s":
        from motorsim.units import speed_in
        print(f"model in {speed_unit}: b/a = {speed_in(model.b / model.a, speed_unit):.6g} {speed_unit}/{unit}"
              + ("" if limit is None else
                 f", top speed {speed_in(abs(model.b / model.a) * limit, speed_unit):.5g} {speed_unit}"))
    print(f"controller: {controller.kind} " + ", ".join(f"{k} = {v!r}" for k, v in controller.settings().items()))
    if unit != "duty":
        print(f"fixed-point gains: none (the firmware's gains act on duty; this model's input is in {unit})")
    elif not encoder_known:
        print("fixed-point gains: none (the firmware's gains act on encoder counts: give the rig's "
              "--counts-per-rev N)")
    else:
        print("fixed-point gains (Q16): " + ", ".join(f"{k} = {v}" for k, v in controller.gains().items()))
    from identify.feedforward import feedforward_constants
    print(feedforward_constants(estimate if estimate is not None else model).describe())
    _print_poles(controller, model)
    largest = float(np.abs(prediction.duty).max())
    print(f"predicted over {args.duration:g} s of {_reference_text(args, reference, controller, speed_unit)}: "
          f"tracking RMS {_in_units(prediction.tracking_rms, controller, speed_unit)}, "
          f"largest input {largest:.4g} {unit}")
    if limit is not None and largest > limit:
        print_to_stderr(f"motorid: warning: the design needs an input of up to {largest:.4g} {unit}, more than the "
                        f"input limit +-{limit:g} {unit}: the drive clips it and the prediction no longer holds; "
                        "slow the reference or the controller, or raise --input-limit if the drive allows it")
    _print_robustness(args, controller, covariance, reference, robustness)
    if args.plot:
        from motorid import plots
        plots.plot_prediction(prediction, args.plot, title=f"{controller.kind}: predicted")
        print(f"figure: {args.plot}")
    return 0


#: The knob each controller is slowed by to keep its design within the input limit, and the factor of each step.
SLOWING_KNOBS = {"mpc": ("duty_weight", 4.0), "lqr": ("duty_weight", 4.0), "lqr-integral": ("duty_weight", 4.0),
                 "lqr-position": ("duty_weight", 4.0), "pi": ("time_constant", 1.5),
                 "position": ("time_constant", 1.5)}
#: Steps tried before the default design is left as it is (and warned of): 4**20 of the weight, 1.5**20 of the time.
SLOWING_STEPS = 20


def _within_limit(args: argparse.Namespace, controller: Controller, prediction: Prediction, reference: Reference,
                  limit: float | None, unit: str) -> tuple[Controller, Prediction]:
    """The design slowed until its predicted input stays within ``limit``, where its knob was left to the default.

    A design by default is one motorid chose: one that asks the drive for more than it gives (a slow motor's
    position loop asked for 16 220 duty) is no design.  Its knob (:data:`SLOWING_KNOBS`) is stepped, at most
    :data:`SLOWING_STEPS` times, until the prediction's largest input is within the limit, and the value chosen
    is said; where no step gets there (a reference beyond what the motor can follow) the design is kept and
    the warning after it says so.  A knob given on the command line is the user's: kept as given."""
    knob = SLOWING_KNOBS.get(controller.kind)
    largest = float(np.abs(prediction.duty).max())
    if limit is None or knob is None or largest <= limit or getattr(args, knob[0], None) is not None:
        return controller, prediction
    name, factor = knob
    settings = controller.settings()
    value = float(settings[name])
    for _ in range(SLOWING_STEPS):
        value *= factor
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                slower = design_controller(controller.kind, controller.model, **{**settings, name: value})
                predicted = slower.predict(reference, args.duration)
        except ValueError:                # past what the design can keep (a phase margin): no slower design
            break
        if caught:                        # a slower design its own checks doubt is no better one
            break
        if float(np.abs(predicted.duty).max()) <= limit:
            print_to_stderr(f"motorid: note: --{name.replace('_', '-')} {value:.3g} (the default "
                            f"{settings[name]:g} asked for an input of {largest:.4g} {unit}, beyond the input limit "
                            f"+-{limit:g} {unit}: slowed until the design stays within it; give "
                            f"--{name.replace('_', '-')} to choose)")
            return slower, predicted
    return controller, prediction


def _sensor(args: argparse.Namespace, estimate: Any) -> str:
    """What the model's data were measured with, for the model line; sets the design's ``counts_per_rev``.

    A model fitted to a speed column came from a speed sensor (a tachometer): no encoder is assumed.
    Without ``--counts-per-rev`` the design uses :data:`DEFAULT_COUNTS_PER_REV` internally (the
    prediction does not depend on it) and prints no fixed-point gains; a model fitted to an angle or
    counts assumes the bench's encoder and says so on stderr.
    """
    given = args.counts_per_rev
    saved = getattr(estimate, "counts_per_rev", None)
    if given is None:
        args.counts_per_rev = saved or DEFAULT_COUNTS_PER_REV
    if estimate is not None and estimate.residual_unit == "rad/s":
        measured = "speed sensor (the model was fitted to a speed column)"
        return measured if given is None else f"{measured}; the rig's encoder {given} counts/rev"
    if given is None and saved:
        return f"the model's encoder {saved} counts/rev"
    if given is None and estimate is not None:
        print_to_stderr(f"motorid: note: a saved model does not say the rig's encoder; assuming "
                        f"{DEFAULT_COUNTS_PER_REV} counts/rev (give --counts-per-rev N)")
    return f"{args.counts_per_rev} counts/rev"


def _print_poles(controller: Controller, model: PlantModel) -> None:
    poles = np.sort_complex(_loop_poles(controller))
    if len(poles):
        print(f"closed-loop poles: {', '.join(f'{p:.4g}' for p in poles)} "
              f"({'stable' if controller.is_stable() else 'UNSTABLE'})")
    else:
        print(f"closed-loop poles: none (no feedback: the {controller.kind} output follows the model's own pole, "
              f"-a = {-model.a:g} 1/s)")


def _in_units(value: float, controller: Controller, speed_unit: str) -> str:
    """A speed in rad/s (or an angle in rad) with, for another speed unit, its value in that unit."""
    text = f"{value:.4g} {controller.reference_unit}"
    if controller.reference_unit == "rad/s" and speed_unit != "rad/s":
        from motorsim.units import speed_in
        text = f"{speed_in(value, speed_unit):.4g} {speed_unit} ({text})"
    return text


def _reference_text(args: argparse.Namespace, reference: Reference, controller: Controller, speed_unit: str) -> str:
    """The reference as the user wrote it (or the default) and, when that had units, in SI."""
    si = f"{reference.describe()} {controller.reference_unit}"
    spec = args.reference
    return si if spec is None or _UNIT_NUMBER.search(spec) is None else f"{spec} ({si})"


def _input_unit_and_limit(args: argparse.Namespace) -> tuple[str, float | None]:
    """The design model's input unit and limit: ``--input-limit``, else the model file's, else 255 for duty and
    100 for %; refused for another unit (volts) without one: its limit is the drive's supply, which only the user
    knows, and a design is made within it."""
    unit, limit = "duty", None
    if getattr(args, "model", None):
        estimate = load_model_file(args.model)
        unit, limit = estimate.input_unit, estimate.input_limit
    if args.input_limit is not None:
        from motorid.commands.importing import check_input_limit
        limit = check_input_limit(args.input_limit, unit)
    if limit is None and unit == "duty":
        limit = float(DUTY_LIMIT)
    if limit is None and unit == "%":
        limit = PERCENT_LIMIT          # a percentage's own full scale: no drive gives more than all of it
    if limit is None:                  # volts: the supply's, which only the user knows
        raise CommandError(f"--input-limit must be given for a model in {unit} that states no input limit (the "
                           f"drive's supply, e.g. --input-limit 12 for a 12 V supply): a design is made and checked "
                           "within it; or give --input-limit to import or identify so the model carries it")
    return unit, limit


def _loop_poles(controller: Controller) -> np.ndarray:
    import control
    _, cy = controller.laws()
    return control.feedback(-(controller.plant() * cy), 1).poles()


def _model_covariance(args: argparse.Namespace) -> np.ndarray | None:
    """The covariance of ``(a, b)`` of the ``--model`` file, of ``(a, b, electrical_time_constant)`` when the model
    has one with a finite variance (the robustness draws it too), of every value of a structure beyond the
    first-order family's (:meth:`motorsim.plant.Plant.values`); None without a covariance."""
    if not getattr(args, "model", None):
        return None
    est = load_model_file(args.model)
    if est.covariance is None or not np.all(np.isfinite(est.covariance[:2, :2])):
        return None
    names = list(est.param_names or ())
    if not isinstance(est.motor(), Motor) and list(est.motor().values()) == names[:len(est.motor().values())]:
        full = np.asarray(est.covariance, dtype=float)[:len(est.motor().values()), :len(est.motor().values())]
        if np.all(np.isfinite(full)):         # a structure beyond the first-order family: all its values drawn
            return full
    rows = [0, 1]
    names = list(est.param_names or ())
    if est.extra.get("electrical_time_constant", 0.0) > 0 and "electrical_time_constant" in names:
        tau = names.index("electrical_time_constant")
        if np.all(np.isfinite(est.covariance[np.ix_([0, 1, tau], [0, 1, tau])])):
            rows.append(tau)
    return np.asarray(est.covariance[np.ix_(rows, rows)], dtype=float)


def _robust_controller(args: argparse.Namespace, controller: Controller, covariance: np.ndarray | None,
                       reference: Any) -> tuple[Controller, Any]:
    from motorsim.robustness import ROBUST_KNOB, robust_design
    if covariance is None:
        raise CommandError("--robust needs the model's covariance: give --model FILE.json saved by "
                           "motorid identify --save from a method with a covariance")
    if controller.kind not in ROBUST_KNOB:
        raise CommandError(f"--robust tunes {', '.join(sorted(ROBUST_KNOB))}, not --controller {controller.kind}")
    settings = controller.settings()
    return robust_design(controller.kind, controller.model, covariance, reference, args.duration,
                         n_draws=_repetitions(args), rng=np.random.default_rng(args.seed), **settings)


def _check_draw_flags(args: argparse.Namespace, covariance: np.ndarray | None) -> None:
    """Refuse ``--repetitions``/``--seed`` where nothing is drawn (no covariance); set their defaults."""
    given = [flag for flag, name in (("--repetitions", "repetitions"), ("--seed", "seed"))
             if getattr(args, name) is not None]
    if given and covariance is None:
        raise CommandError(f"{', '.join(given)} set{'s' if len(given) == 1 else ''} the plants drawn from a --model "
                           "file's covariance, and this design has none (--a/--b, or a model without a covariance): "
                           "nothing would be drawn")
    args.repetitions = 100 if args.repetitions is None else args.repetitions
    args.seed = 0 if args.seed is None else args.seed


#: The most plants ``--repetitions`` draws (100 000 ran for hours: some 0.05-0.3 s a draw).
MAX_DRAWS = 1000


def _repetitions(args: argparse.Namespace) -> int:
    if not 1 <= args.repetitions <= MAX_DRAWS:
        raise CommandError(f"--repetitions must be in 1...{MAX_DRAWS}, got {args.repetitions!r}: each draw is a "
                           "closed loop analysed in full (margins, tracking), and --robust analyses every draw at "
                           f"each setting it tries; {MAX_DRAWS} draws give the 95th percentile's probability "
                           "within +-1.4 %")
    return int(args.repetitions)


def _print_robustness(args: argparse.Namespace, controller: Controller, covariance: np.ndarray | None,
                      reference: Any, robustness: Any) -> None:
    """The margins at the point estimate and, with a covariance, across the drawn plants, and warnings."""
    from motorsim.robustness import analyse_robustness, loop_margins
    print(f"margins at the point estimate: {loop_margins(controller).describe()}")
    if controller.model.electrical_time_constant:
        print(f"  (the full model, electrical time constant {controller.model.electrical_time_constant:g} s "
              f"included; the design's first-order part alone: {controller.first_order_margins().describe()})")
    if covariance is None:
        print("robustness across the model's uncertainty: give --model FILE.json with a covariance")
        return
    if robustness is None:
        robustness = analyse_robustness(controller, covariance, reference, args.duration,
                                        n_draws=_repetitions(args), rng=np.random.default_rng(args.seed))
    r = robustness
    unit = controller.reference_unit
    gm = r.worst_gain_margin
    gm_text = "inf" if math.isinf(gm) else f"{20 * math.log10(gm):.3g} dB"
    print(f"across the model's uncertainty ({r.method}, --seed {args.seed}):")
    print(f"  tracking RMS: worst {r.worst_rms:.4g} {unit}, {r.percentile:g}th percentile {r.percentile_rms:.4g} "
          f"{unit} (point estimate {r.tracking_rms:.4g})")
    print(f"  smallest margins: gain {gm_text}, phase {r.worst_phase_margin:.3g} deg, "
          f"delay {r.worst_delay_margin * 1e3:.3g} ms; unstable {100 * r.unstable:.3g} %, "
          f"badly damped {100 * r.badly_damped:.3g} %"
          + (f", b of the other sign {100 * r.other_sign:.3g} %" if r.other_sign else "")
          + (f"; left out (a <= 0) {100 * r.rejected:.3g} % of the draws" if r.n_rejected else ""))
    for text in r.warnings():
        print(f"warning: {text}")
