"""The estimators by name: ``fit(recordings, method=...)`` and ``available_methods()``.

Add an estimator by adding one line to ``_METHODS``; the CLI and the sweeps
pick it up by name.
"""
from __future__ import annotations

from typing import Callable

from .estimate import Estimate
from .friction import fit_output_error_friction
from .instrumental import fit_instrumental_variables
from .output_error import fit_output_error
from .regression import fit_euler_ls, fit_zoh_ls

__all__ = ["fit", "available_methods", "method_options", "DEFAULT_METHOD"]

_METHODS: dict[str, Callable[..., Estimate]] = {
    "euler-ls": fit_euler_ls,
    "zoh-ls": fit_zoh_ls,
    "oe": fit_output_error,
    "iv": fit_instrumental_variables,
    "oe-friction": fit_output_error_friction,
}

#: The most accurate method available (``motorid identify`` without ``--method``).
DEFAULT_METHOD = "oe"


def available_methods() -> list[str]:
    """Names accepted by :func:`fit`."""
    return list(_METHODS)


def method_options(method: str) -> tuple[str, ...]:
    """Names of the keyword options the named method accepts (besides the recordings)."""
    import inspect
    if method not in _METHODS:
        raise ValueError(f"method must be one of {available_methods()}, got {method!r}")
    return tuple(inspect.signature(_METHODS[method]).parameters)[1:]


def fit(recordings, method: str = DEFAULT_METHOD, **options) -> Estimate:
    """Identify ``a`` and ``b`` with the named method.

    Parameters
    ----------
    recordings : Recording or sequence of Recording
        Several recordings of the same motor are pooled into one estimate.
    method : str
        One of :func:`available_methods`.
    **options
        Passed to the method.

    Returns
    -------
    Estimate
    """
    if method not in _METHODS:
        raise ValueError(f"method must be one of {available_methods()}, got {method!r}")
    return _METHODS[method](recordings, **options)
