"""The estimators by name: ``fit(recordings, method=...)``, ``available_methods()``, ``method_function(name)``.

Add an estimator by adding one line to ``_METHODS``; the CLI and the sweeps
pick it up by name.  Every estimate's ``method`` is one of these names, and
``fit(recordings, estimate.method, **options)`` reproduces it with the options
it was made with (e.g. ``fit_bias=True`` for ``oe`` with a constant acceleration).

The registry names each estimator as ``"module:function"`` of this package rather than
holding the function, so that listing the names imports no estimator.  Every command's
``--help`` lists the methods (``--method`` choices), and the estimator modules import
scipy.optimize, scipy.linalg and scipy.sparse at the top: with the functions registered,
``motorid --help`` took 588 ms, 0.43 x ``import control`` measured in the same
``motorid bench startup`` run (goal 0.25 x), against 262 ms, 0.14 x, with the names.
A test resolves every entry, so a misspelt one fails there rather than at a user's fit.

Each estimator's keyword options are declared here too (``_OPTIONS``: name, kind, default and
a one-line help per option, :class:`EstimatorOption`), without importing it: :func:`fit` and
``motorid identify`` check what they are given against the declaration and name the method,
the option and the ones it takes; a test checks every declaration against its function.
"""
from __future__ import annotations

import dataclasses
from typing import Any, Callable, Mapping

from motorsim.checks import ParameterError, ParameterTypeError
from motorsim.lazy import load
from motorsim.recording import Recording

from .estimate import Estimate
from .model_structures import ModelStructure

__all__ = ["fit", "available_methods", "method_function", "method_options", "option_declarations", "check_options",
           "EstimatorOption", "candidate_function", "DEFAULT_METHOD"]

#: name -> "module:function" of this package (its module imported when first used), or the function itself
_METHODS: dict[str, str | Callable[..., Estimate]] = {
    "euler-ls": "regression:fit_euler_ls",
    "zoh-ls": "regression:fit_zoh_ls",
    "oe": "output_error:fit_output_error",
    "iv": "instrumental:fit_instrumental_variables",
    "oe-friction": "friction:fit_output_error_friction",
    "iv-reference": "closed_loop:fit_reference_iv",
    "oe-electrical": "electrical:fit_output_error_electrical",
    "pem-disturbance": "prediction_error:fit_prediction_error",
}

#: What ``fit`` does when no method is named: the delay and the structure chosen by evidence
#: (:func:`identify.selection.fit_selected`), the same for ``identify.fit`` and ``motorid identify``.
DEFAULT_METHOD = "auto"
_DEFAULT_ENTRY = "selection:fit_selected"


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


def _input_delay(default: int | str = 0, kind: str = "int or 'auto'") -> EstimatorOption:
    return EstimatorOption("input_delay", kind, default, "whole samples between a duty commanded and its reaching "
                           "the motor" + (", or 'auto': the shortest within the noise of the best" if "auto" in kind
                                          else ""))


_FIX_BIAS = EstimatorOption("fix_bias", "bool", False, "hold the bias (constant acceleration d) at 0")

#: method -> the keyword options it takes, in its signature's order (a test checks each against its function)
_OPTIONS: dict[str, tuple[EstimatorOption, ...]] = {
    DEFAULT_METHOD: (
        _input_delay("auto"),
        EstimatorOption("structures", "sequence of str or None", None,
                        "the registered structures to choose among (identify.structures(); default all)"),
        EstimatorOption("fix_bias", "bool", False, "hold the bias at 0 in the friction structures")),
    "euler-ls": (),
    "zoh-ls": (),
    "oe": (
        _input_delay(),
        EstimatorOption("fit_bias", "bool", False, "also fit a constant acceleration d (the bias structure)"),
        EstimatorOption("jac", "'analytic', '2-point' or '3-point'", "analytic",
                        "the Jacobian: analytic sensitivities or finite differences"),
        EstimatorOption("covariance", "'auto' or 'gauss-newton'", "auto",
                        "intervals that hold when the noise is not white, or the fit's own (white noise assumed)")),
    "iv": (
        _input_delay(),
        EstimatorOption("iterations", "int >= 1", 3, "instrumental-variable passes after the zoh-ls start")),
    "oe-friction": (
        _input_delay(),
        _FIX_BIAS,
        EstimatorOption("dead_zone", "bool", True, "also fit a dead zone of the input"),
        EstimatorOption("static_friction", "bool", False,
                        "also fit a static friction above the friction (stiction; needs dead_zone false)")),
    "iv-reference": (_input_delay(0, "int"),),
    "oe-electrical": (_input_delay(),),
    "pem-disturbance": (
        _input_delay(0, "int"),
        EstimatorOption("friction", "bool", True, "also fit Coulomb friction c"),
        EstimatorOption("disturbance_pole", "float in [0, 1] or None", None,
                        "hold the torque disturbance's pole per sample (1: a random walk) instead of fitting it")),
}


#: method -> "module:function" fitting one structure as a candidate of the default's selection, called as
#: ``function(recordings, segments, input_delay, structure, refine=..., fix_bias=...) -> CandidateFit``
_CANDIDATES = {
    "oe": "output_error:structure_candidate",
    "oe-friction": "friction:structure_candidate",
    "oe-electrical": "electrical:structure_candidate",
}

#: methods made for closed-loop recordings (``iv-reference`` needs their reference column)
_CLOSED_LOOP_ONLY = frozenset({"iv-reference", "pem-disturbance"})
#: methods of structures beyond the first-order motor's family (a second pole)
_BEYOND_FIRST_ORDER = frozenset({"oe-electrical"})

def available_methods(*, open_loop: bool = False, first_order: bool = False) -> list[str]:
    """The estimators :func:`fit` can be told to use (besides the default, ``"auto"``).

    Parameters
    ----------
    open_loop : bool
        Leave out the methods made for closed-loop recordings (``iv-reference``, ``pem-disturbance``):
        the list "all methods" means for open-loop runs (the demo, the sweeps).
    first_order : bool
        Leave out the estimators of structures beyond the first-order motor (``oe-electrical``):
        with ``open_loop``, what "all methods" means for the article's experiment (the demo, the sweeps).
    """
    return [m for m in _METHODS if not (open_loop and m in _CLOSED_LOOP_ONLY)
            and not (first_order and m in _BEYOND_FIRST_ORDER)]


def method_function(method: str) -> Callable[..., Estimate]:
    """The estimator registered as ``method`` (its keyword options are its own).

    Parameters
    ----------
    method : str
        One of :func:`available_methods`.
    """
    if method != DEFAULT_METHOD and method not in _METHODS:
        raise ParameterError(f"method must be one of {[DEFAULT_METHOD, *available_methods()]}, got {method!r}")
    entry = _DEFAULT_ENTRY if method == DEFAULT_METHOD else _METHODS[method]
    if callable(entry):
        return entry
    return load(f".{entry}", __package__)


def candidate_function(structure: ModelStructure) -> Callable[..., Any]:
    """The function that fits ``structure`` as a candidate of the default's selection (by its estimator).

    Parameters
    ----------
    structure : ModelStructure
        A registered structure; its ``method`` names the estimator.
    """
    if structure.method not in _CANDIDATES:
        raise ParameterError(f"structure {structure.name!r} has no candidate fit: its method must be one of "
                             f"{list(_CANDIDATES)}, got {structure.method!r}")
    return load(f".{_CANDIDATES[structure.method]}", __package__)


def option_declarations(method: str) -> tuple[EstimatorOption, ...]:
    """The keyword options the named method takes (besides the recordings), as declared.

    Parameters
    ----------
    method : str
        ``"auto"`` or one of :func:`available_methods`.

    Examples
    --------
    >>> from identify import option_declarations
    >>> [(o.name, o.default) for o in option_declarations("oe-friction")]
    [('input_delay', 0), ('fix_bias', False), ('dead_zone', True), ('static_friction', False)]
    """
    if method != DEFAULT_METHOD and method not in _METHODS:
        raise ParameterError(f"method must be one of {[DEFAULT_METHOD, *available_methods()]}, got {method!r}")
    if method not in _OPTIONS:
        raise ParameterError(f"method {method!r} declares no options: add its line to identify.methods._OPTIONS")
    return _OPTIONS[method]


def method_options(method: str) -> tuple[str, ...]:
    """Names of the keyword options the named method takes (besides the recordings), as declared."""
    return tuple(o.name for o in option_declarations(method))


def check_options(method: str, options: Mapping[str, Any]) -> None:
    """Refuse an option the named method does not declare, naming the method, the option and the ones it takes.

    Parameters
    ----------
    method : str
        ``"auto"`` or one of :func:`available_methods`.
    options : mapping of str to object
        The keyword options to be given to it.

    Raises
    ------
    motorsim.checks.ParameterError
        (a ``ValueError``) For a method that is not registered; ``ParameterTypeError`` (also a
        ``TypeError``, as Python's own for an unexpected keyword) for an option it does not take.
    """
    accepted = method_options(method)
    unknown = [name for name in options if name not in accepted]
    if unknown:
        takes = f"its options are {', '.join(accepted)}" if accepted else "it takes no options"
        raise ParameterTypeError(f"method {method!r} has no option {unknown[0]!r}: {takes}")


def fit(recordings: Recording | list[Recording], method: str = DEFAULT_METHOD, *, outliers: str = "refuse",
        **options: Any) -> Estimate:
    """Identify ``a`` and ``b``: by default choosing the input delay and the model structure by evidence.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Several recordings of the same motor are pooled into one estimate.
    method : str
        ``"auto"`` (default, what ``motorid identify`` does too): the input delay ``0 ... 10``
        and the structure (linear, bias, Coulomb friction, dead zone) chosen by evidence
        (:func:`identify.selection.fit_selected`; the estimate's ``selection`` says what was
        compared).  Or one of :func:`available_methods` to force that estimator.
    outliers : {"refuse", "drop", "keep"}
        Corrupted samples (a row no motor can produce, an isolated residual outlier after the
        fit): refused with :class:`identify.errors.CorruptedSamplesError` (default, as
        ``motorid identify`` does), dropped as gaps and the fit repeated (``--drop-outliers``),
        or kept (no screening).  :func:`identify.screening.screened_fit` also returns what it dropped.
    **options
        Passed to the method.  Each method's options:

        - ``auto``: ``input_delay`` (``"auto"`` or samples), ``structures`` (subset of
          ``("linear", "bias", "friction", "dead-zone")``), ``fix_bias``.
        - ``oe``: ``input_delay`` (default 0, or ``"auto"``), ``fit_bias``, ``jac``, ``covariance``.
        - ``oe-friction``: ``input_delay`` (default 0, or ``"auto"``), ``fix_bias``, ``dead_zone``,
          ``static_friction``.
        - ``iv``: ``input_delay`` (default 0, or ``"auto"``).
        - ``euler-ls``, ``zoh-ls``: none.

        :func:`option_declarations` lists them for a method (kind, default, help); an option the
        method does not take is refused with a ``TypeError`` (and ``ValueError``) naming the
        method, the option and the ones it takes.

    Returns
    -------
    Estimate

    Examples
    --------
    Simulate the article's motor under one of its sines, fit it, and get the
    transfer function (noise-free, so the fit is exact to rounding):

    >>> from identify import fit
    >>> from motorsim.excitation import Sine
    >>> from motorsim.plant import Motor
    >>> from motorsim.rig import Experiment, SimRig
    >>> rec = SimRig(Motor(25.0, 3.0)).run(Experiment(Sine(10.0, 200), 0.005, 5.0))
    >>> est = fit(rec, method="oe")
    >>> print(f"a = {est.a:.3f} 1/s, b = {est.b:.4f} (rad/s^2)/duty")
    a = 25.000 1/s, b = 3.0000 (rad/s^2)/duty
    >>> tf = est.transfer_function()           # b / (s + a), duty to speed
    >>> print(f"pole {tf.poles()[0].real:.3f} 1/s, static gain {float(tf.dcgain()):.4f} (rad/s)/duty")
    pole -25.000 1/s, static gain 0.1200 (rad/s)/duty
    """
    from .screening import screened_fit
    estimator = method_function(method)
    check_options(method, options)
    return screened_fit(recordings, estimator, options, outliers=outliers, name=method).estimate
