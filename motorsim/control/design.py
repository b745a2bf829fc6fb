"""The design entry point: every controller by ``kind`` (:data:`CONTROLLERS`), :func:`design_controller`,
and the knobs of a kind found among parsed arguments (:func:`settings_from`)."""
from __future__ import annotations

import dataclasses
from typing import Any, Mapping

from ..checks import ParameterError
from .base import Controller
from .feedforward import Feedforward
from .lqr import LQRPosition, LQRSpeed, LQRSpeedIntegral
from .model import PlantModel
from .mpc import OneStepMPC
from .pi import PISpeed
from .position import PositionPD

__all__ = ["CONTROLLERS", "design_controller", "settings_from"]

#: Controllers by ``kind`` (``motorid control design --controller``).
CONTROLLERS: dict[str, type[Controller]] = {c.kind: c for c in (OneStepMPC, PISpeed, PositionPD, Feedforward,
                                                                 LQRSpeed, LQRSpeedIntegral, LQRPosition)}


def design_controller(kind: str, model: PlantModel, **settings: Any) -> Controller:
    """The controller ``kind`` (a key of :data:`CONTROLLERS`) designed from ``model``.

    Parameters
    ----------
    kind : str
        ``mpc``, ``pi``, ``position``, ``feedforward``, ``lqr`` or ``lqr-position``.
    model : PlantModel
        The motor model.
    **settings
        The controller's knobs (``duty_weight``, ``time_constant``, ``feedforward``, ``derivative``).
    """
    if kind not in CONTROLLERS:
        raise ParameterError(f"controller must be one of {', '.join(CONTROLLERS)}, got {kind!r}")
    cls = CONTROLLERS[kind]
    known = {f.name for f in dataclasses.fields(cls)} - {"model"}
    unknown = set(settings) - known
    if unknown:
        raise ParameterError(f"controller {kind!r} takes {sorted(known) or 'no settings'}, got {sorted(unknown)}")
    return cls(model, **settings)



def settings_from(values: Mapping[str, Any], kind: str) -> dict[str, Any]:
    """The knobs of controller ``kind`` found in ``values`` (e.g. parsed CLI arguments), others ignored."""
    known = {f.name for f in dataclasses.fields(CONTROLLERS[kind])} - {"model"}
    return {k: v for k, v in values.items() if k in known and v is not None}
