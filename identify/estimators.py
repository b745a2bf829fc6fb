"""The estimators as objects: each one's name, function, declared options and what it is made for.

A structure names the estimator that fits it by object (``ModelStructure.estimator``), and the
registry of names (:mod:`identify.methods`: ``identify.fit(rec, method)``, ``motorid identify
--method``) lists the same objects, so one estimator is described once: its name, the function
that fits it, its keyword options (:class:`EstimatorOption`, checked by ``fit`` and the command
line), the function that fits a structure of it as a candidate of the default's selection, and
whether it is made for closed-loop recordings or for a structure beyond the first-order motor.

Each function is named as ``"module:function"`` of this package and loaded on first use:
listing the estimators imports none of them (every command's ``--help`` lists the methods, and
the estimator modules import scipy's optimisers at the top; see :mod:`identify.methods`).
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable

from motorsim.checks import ParameterError
from motorsim.lazy import load

from .data import DEFAULT_INPUT_DELAY

__all__ = ["Estimator", "EstimatorOption", "DEFAULT", "EULER_LS", "ZOH_LS", "OE", "IV", "OE_FRICTION",
           "IV_REFERENCE", "OE_ELECTRICAL", "OE_ASYMMETRIC", "OE_DRIVE_LIMIT", "PEM_DISTURBANCE",
           "REGISTERED_ESTIMATORS", "linear_estimator"]


@dataclasses.dataclass(frozen=True)
class EstimatorOption:
    """One keyword option an estimator takes: ``identify.fit(recordings, method, NAME=value)``.

    Attributes
    ----------
    name : str
        The keyword.
    kind : str
        What it takes, in words (``"int or 'auto'"``, ``"bool"``, ...); the estimator checks the value.
    default : object
        Its value when not given.
    help : str
        One line: what it does.
    """

    name: str
    kind: str
    default: Any
    help: str


@dataclasses.dataclass(frozen=True, eq=False)
class Estimator:
    """An estimator: ``identify.fit(recordings, name, **options)``.

    Attributes
    ----------
    name : str
        The name ``identify.fit`` and ``motorid identify --method`` take; every estimate's ``method``.
    entry : str or callable
        ``"module:function"`` of this package (loaded on first use), or the function itself.
    options : tuple of EstimatorOption
        Its keyword options, in its signature's order (a test checks each against the function).
    candidate : str
        ``"module:function"`` fitting one of its structures as a candidate of the default's selection,
        called as ``function(recordings, segments, input_delay, structure, refine=..., fix_bias=...)``;
        ``""`` when the default does not use it.
    closed_loop_only : bool
        Made for closed-loop recordings (``iv-reference`` needs their reference column).
    beyond_first_order : bool
        Fits a structure beyond the first-order motor's family (a second pole, a gain per direction, a drive limit).
    """

    name: str
    entry: str | Callable[..., Any]
    options: tuple[EstimatorOption, ...] = ()
    candidate: str = ""
    closed_loop_only: bool = False
    beyond_first_order: bool = False

    def function(self) -> Callable[..., Any]:
        """The function that fits it (its module imported on first use)."""
        return self.entry if callable(self.entry) else load(f".{self.entry}", __package__)

    def candidate_function(self) -> Callable[..., Any]:
        """The function that fits one of its structures as a candidate of the default's selection."""
        if not self.candidate:
            raise ParameterError(f"estimator {self.name!r} fits no candidate of the default's selection")
        return load(f".{self.candidate}", __package__)

    def option_names(self) -> tuple[str, ...]:
        """Names of its keyword options."""
        return tuple(o.name for o in self.options)

    def __repr__(self) -> str:
        return f"<Estimator {self.name!r}>"


def _input_delay(default: int | str = DEFAULT_INPUT_DELAY, kind: str = "int or 'auto'") -> EstimatorOption:
    """The ``input_delay`` option: :data:`identify.data.DEFAULT_INPUT_DELAY` where the method can search it,
    else the fixed ``default`` given (``iv-reference``, ``pem-disturbance``: 0)."""
    return EstimatorOption("input_delay", kind, default, "whole samples between a duty commanded and its reaching "
                           "the motor" + (", or 'auto': the shortest within the noise of the best" if "auto" in kind
                                          else ""))


_FIX_BIAS = EstimatorOption("fix_bias", "bool", False, "hold the bias (constant acceleration d) at 0")

#: What ``fit`` does when no method is named: the delay and the structure chosen by evidence
#: (:func:`identify.default.selection.fit_selected`), the same for ``identify.fit`` and ``motorid identify``.
DEFAULT = Estimator("auto", "default.selection:fit_selected", (
    _input_delay(),
    EstimatorOption("structures", "sequence of str or None", None,
                    "the registered structures to choose among (identify.structures(); default all)"),
    EstimatorOption("fix_bias", "bool", False, "hold the bias at 0 in the friction structures")))
EULER_LS = Estimator("euler-ls", "fits.regression:fit_euler_ls")
ZOH_LS = Estimator("zoh-ls", "fits.regression:fit_zoh_ls")
OE = Estimator("oe", "fits.output_error:fit_output_error", (
    _input_delay(),
    EstimatorOption("fit_bias", "bool", False, "also fit a constant acceleration d (the bias structure)"),
    EstimatorOption("jac", "'analytic', '2-point' or '3-point'", "analytic",
                    "the Jacobian: analytic sensitivities or finite differences"),
    EstimatorOption("covariance", "'auto' or 'gauss-newton'", "auto",
                    "intervals that hold when the noise is not white, or the fit's own (white noise assumed)")),
    candidate="fits.output_error:structure_candidate")
IV = Estimator("iv", "fits.instrumental:fit_instrumental_variables", (
    _input_delay(),
    EstimatorOption("iterations", "int >= 1", 3, "instrumental-variable passes after the zoh-ls start")))
OE_FRICTION = Estimator("oe-friction", "fits.friction:fit_output_error_friction", (
    _input_delay(),
    _FIX_BIAS,
    EstimatorOption("dead_zone", "bool", True, "also fit a dead zone of the input"),
    EstimatorOption("static_friction", "bool", False,
                    "also fit a static friction above the friction (stiction; needs dead_zone false)")),
    candidate="fits.friction:structure_candidate")
IV_REFERENCE = Estimator("iv-reference", "fits.closed_loop:fit_reference_iv", (_input_delay(0, "int"),),
                         closed_loop_only=True)
OE_ELECTRICAL = Estimator("oe-electrical", "fits.electrical:fit_output_error_electrical", (_input_delay(),),
                          candidate="fits.electrical:structure_candidate", beyond_first_order=True)
OE_ASYMMETRIC = Estimator("oe-asymmetric", "fits.asymmetry:fit_output_error_asymmetric", (
    _input_delay(),
    EstimatorOption("covariance", "'auto' or 'gauss-newton'", "auto",
                    "intervals that hold when the noise is not white, or the fit's own (white noise assumed)")),
    beyond_first_order=True)
OE_DRIVE_LIMIT = Estimator("oe-drive-limit", "fits.drive_limit:fit_output_error_drive_limit", (
    _input_delay(),
    EstimatorOption("covariance", "'auto' or 'gauss-newton'", "auto",
                    "intervals that hold when the noise is not white, or the fit's own (white noise assumed)")),
    beyond_first_order=True)
PEM_DISTURBANCE = Estimator("pem-disturbance", "fits.prediction_error:fit_prediction_error", (
    _input_delay(0, "int"),
    EstimatorOption("friction", "bool", True, "also fit Coulomb friction c"),
    EstimatorOption("disturbance_pole", "float in [0, 1] or None", None,
                    "hold the torque disturbance's pole per sample (1: a random walk) instead of fitting it")),
    closed_loop_only=True)

def linear_estimator(name: str, structure: str) -> Estimator:
    """The estimator ``name`` fitting the registered linear ``structure`` by output error
    (:func:`identify.fits.structure_fit.fit_linear_structure`): what a new linear structure names as its
    ``estimator``; it is listed by name from the structure registry (:data:`identify.methods.ESTIMATORS`)."""
    def fit(recordings: Any, *, input_delay: int | str = DEFAULT_INPUT_DELAY) -> Any:
        return load(".fits.structure_fit:fit_linear_structure", __package__)(recordings, structure=structure,
                                                                        input_delay=input_delay)
    fit.__name__ = fit.__qualname__ = f"fit_{structure.replace('-', '_')}"
    return Estimator(name, fit, (_input_delay(),), beyond_first_order=True)


#: Every estimator a user can name, in the order ``available_methods()`` lists them.
REGISTERED_ESTIMATORS: tuple[Estimator, ...] = (EULER_LS, ZOH_LS, OE, IV, OE_FRICTION, IV_REFERENCE, OE_ELECTRICAL,
                                                OE_ASYMMETRIC, OE_DRIVE_LIMIT, PEM_DISTURBANCE)
