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
"""
from __future__ import annotations

import inspect
from typing import Any, Callable

from motorsim.checks import ParameterError
from motorsim.lazy import load
from motorsim.recording import Recording

from .estimate import Estimate
from .model_structures import ModelStructure

__all__ = ["fit", "available_methods", "method_function", "method_options", "candidate_function", "DEFAULT_METHOD"]

#: name -> "module:function" of this package (its module imported when first used), or the function itself
_METHODS: dict[str, str | Callable[..., Estimate]] = {
    "euler-ls": "regression:fit_euler_ls",
    "zoh-ls": "regression:fit_zoh_ls",
    "oe": "output_error:fit_output_error",
    "iv": "instrumental:fit_instrumental_variables",
    "oe-friction": "friction:fit_output_error_friction",
    "iv-reference": "closed_loop:fit_reference_iv",
    "oe-electrical": "electrical:fit_output_error_electrical",
}

#: What ``fit`` does when no method is named: the delay and the structure chosen by evidence
#: (:func:`identify.selection.fit_selected`), the same for ``identify.fit`` and ``motorid identify``.
DEFAULT_METHOD = "auto"
_DEFAULT_ENTRY = "selection:fit_selected"

#: method -> "module:function" fitting one structure as a candidate of the default's selection, called as
#: ``function(recordings, segments, input_delay, structure, refine=..., fix_bias=...) -> CandidateFit``
_CANDIDATES = {
    "oe": "output_error:structure_candidate",
    "oe-friction": "friction:structure_candidate",
    "oe-electrical": "electrical:structure_candidate",
}

#: methods that need a closed-loop recording's reference column
_CLOSED_LOOP_ONLY = frozenset({"iv-reference"})
#: methods of structures beyond the first-order motor's family (a second pole)
_BEYOND_FIRST_ORDER = frozenset({"oe-electrical"})

def available_methods(*, open_loop: bool = False, first_order: bool = False) -> list[str]:
    """The estimators :func:`fit` can be told to use (besides the default, ``"auto"``).

    Parameters
    ----------
    open_loop : bool
        Leave out the methods that need a closed-loop recording's reference (``iv-reference``):
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


def method_options(method: str) -> tuple[str, ...]:
    """Names of the keyword options the named method accepts (besides the recordings)."""
    return tuple(inspect.signature(method_function(method)).parameters)[1:]


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

        :func:`method_options` lists them for a method.

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
    return screened_fit(recordings, method_function(method), options, outliers=outliers, name=method).estimate
