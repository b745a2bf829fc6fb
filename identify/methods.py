"""The estimators by name: ``fit(recordings, method=...)``, ``available_methods()``, ``method_function(name)``.

Every estimator is an object of :mod:`identify.estimators` (its name, function, declared options,
candidate fit and what it is made for); add one there and to :data:`ESTIMATORS`, and a structure it
fits names it as its ``estimator``.  A structure's own estimator is listed from the structure
registry (:data:`identify.model_structures.REGISTERED`): a new structure adds no line here.
The CLI and the sweeps pick it up by name.  Every estimate's
``method`` is one of these names, and ``fit(recordings, estimate.method, **options)`` reproduces it
with the options it was made with (e.g. ``fit_bias=True`` for ``oe`` with a constant acceleration).

An estimator names its function as ``"module:function"`` of this package rather than holding
it, so that listing the names imports no estimator.  Every command's ``--help`` lists the
methods (``--method`` choices), and the estimator modules import scipy.optimize, scipy.linalg
and scipy.sparse at the top: with the functions registered, ``motorid --help`` took 588 ms,
0.43 x ``import control`` measured in the same ``motorid bench startup`` run (goal 0.25 x),
against 262 ms, 0.14 x, with the names.  A test resolves every entry, so a misspelt one fails
there rather than at a user's fit.

Each estimator's keyword options are declared with it (name, kind, default and a one-line help
per option, :class:`EstimatorOption`), without importing it: :func:`fit` and ``motorid
identify`` check what they are given against the declaration and name the method, the option
and the ones it takes; a test checks every declaration against its function.  The input delay's
default is :data:`identify.data.DEFAULT_INPUT_DELAY` for every estimator that can search it.
"""
from __future__ import annotations

from typing import Any, Callable, Mapping

from motorsim.checks import ParameterError, ParameterTypeError
from motorsim.recording import Recording

from .estimate import Estimate
from .estimators import DEFAULT, REGISTERED_ESTIMATORS, Estimator, EstimatorOption
from .model_structures import REGISTERED, ModelStructure

__all__ = ["fit", "available_methods", "method_function", "method_options", "option_declarations", "check_options",
           "EstimatorOption", "Estimator", "estimator", "candidate_function", "DEFAULT_METHOD", "ESTIMATORS"]

#: Every estimator by name (:mod:`identify.estimators`: each one's function, options and what it is made for),
#: then the estimator each registered structure names, by object: a structure's own estimator (a new
#: structure's, :func:`identify.fits.structure_fit.linear_estimator`) is listed from the structure registry.
ESTIMATORS: dict[str, Estimator] = {e.name: e for e in REGISTERED_ESTIMATORS}
for _s in REGISTERED:
    if ESTIMATORS.setdefault(_s.estimator.name, _s.estimator) is not _s.estimator:
        raise RuntimeError(f"structure {_s.name!r} names an estimator {_s.estimator.name!r} that is another's")

#: What ``fit`` does when no method is named: the delay and the structure chosen by evidence
#: (:func:`identify.default.selection.fit_selected`), the same for ``identify.fit`` and ``motorid identify``.
DEFAULT_METHOD = DEFAULT.name


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
    return [name for name, e in ESTIMATORS.items() if not (open_loop and e.closed_loop_only)
            and not (first_order and e.beyond_first_order)]


def estimator(method: str | Estimator) -> Estimator:
    """The estimator called ``method`` (``"auto"``, the default, included; an estimator is returned as it is).

    Parameters
    ----------
    method : str or Estimator
        ``"auto"`` or one of :func:`available_methods`.
    """
    if isinstance(method, Estimator):
        return method
    if method == DEFAULT_METHOD:
        return DEFAULT
    if method not in ESTIMATORS:
        raise ParameterError(f"method must be one of {[DEFAULT_METHOD, *available_methods()]}, got {method!r}")
    return ESTIMATORS[method]


def method_function(method: str) -> Callable[..., Estimate]:
    """The estimator registered as ``method`` (its keyword options are its own).

    Parameters
    ----------
    method : str
        One of :func:`available_methods`.
    """
    return estimator(method).function()


def candidate_function(structure: ModelStructure) -> Callable[..., Any]:
    """The function that fits ``structure`` as a candidate of the default's selection (by its estimator).

    Parameters
    ----------
    structure : ModelStructure
        A registered structure; its ``estimator`` fits it.
    """
    if not structure.estimator.candidate:
        raise ParameterError(f"structure {structure.name!r} has no candidate fit: its estimator must be one of "
                             f"{[e.name for e in ESTIMATORS.values() if e.candidate]}, got {structure.method!r}")
    return structure.estimator.candidate_function()


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
    [('input_delay', 'auto'), ('fix_bias', False), ('dead_zone', True), ('static_friction', False)]
    """
    return estimator(method).options


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
        (:func:`identify.default.selection.fit_selected`; the estimate's ``selection`` says what was
        compared).  Or one of :func:`available_methods` to force that estimator.
    outliers : {"refuse", "drop", "keep"}
        Corrupted samples (a row no motor can produce, an isolated residual outlier after the
        fit): refused with :class:`identify.errors.CorruptedSamplesError` (default, as
        ``motorid identify`` does), dropped as gaps and the fit repeated (``--drop-outliers``),
        or kept (no screening).  :func:`identify.checks.screening.screened_fit` also returns what it dropped.
    **options
        Passed to the method.  Each method's options:

        - ``auto``: ``input_delay`` (``"auto"`` or samples), ``structures`` (subset of
          ``("linear", "bias", "friction", "dead-zone")``), ``fix_bias``.
        - ``oe``: ``input_delay`` (``"auto"``, the default, or samples), ``fit_bias``, ``jac``,
          ``covariance``.
        - ``oe-friction``: ``input_delay`` (``"auto"``, the default, or samples), ``fix_bias``,
          ``dead_zone``, ``static_friction``.
        - ``iv``, ``oe-electrical``: ``input_delay`` (``"auto"``, the default, or samples).
        - ``iv-reference``, ``pem-disturbance``: ``input_delay`` (samples, default 0), and their own.

        Every estimator that can search for the input delay does so unless told one
        (:data:`identify.data.DEFAULT_INPUT_DELAY`), as ``motorid identify --method`` does.
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
    from .checks.screening import screened_fit
    estimator = method_function(method)
    check_options(method, options)
    return screened_fit(recordings, estimator, options, outliers=outliers, name=method).estimate
