"""The model structures, registered by name: ``identify.structures()``.

Each structure is one object (:class:`~identify.structures.base.ModelStructure`): its parameter
names, units and bounds, the estimator that fits it, and its conversions (to the simulator's
plant, to a python-control system, to a model output on a recording's segment).  The
estimators, the default's selection (which iterates over :func:`structures` in the order
registered, simplest first), validation, the frequency view and control design ask it.

Adding a structure is one module of this package, one line in :data:`REGISTERED` and its
tests (``docs/develop.md`` walks through an example).
"""
from __future__ import annotations

from typing import Mapping, Sequence

from motorsim.checks import ParameterError
from motorsim.plant import register_structures

from .base import ModelStructure, Parameter
from .current_limit import CurrentLimit
from .drive_map import AsymmetricGain, DriveLimit
from .first_order import CoulombFriction, DeadZone, FirstOrder, FirstOrderBias, Stiction
from .second_order import SecondOrder
from .two_mass import TwoMass, TwoMassLoad

__all__ = ["ModelStructure", "Parameter", "REGISTERED", "structures", "structure", "structure_of",
           "structure_fitted"]

#: Every structure motorid knows, simplest first (the default's order of simplicity).
REGISTERED: tuple[ModelStructure, ...] = (FirstOrder(), FirstOrderBias(), CoulombFriction(), DeadZone(), Stiction(),
                                          SecondOrder(), AsymmetricGain(), DriveLimit(), CurrentLimit(), TwoMass(),
                                          TwoMassLoad())


def structures(*, in_default: bool = False) -> Mapping[str, ModelStructure]:
    """The registered structures by name, simplest first.

    Parameters
    ----------
    in_default : bool
        Only those the default estimator considers.

    Examples
    --------
    >>> import identify
    >>> list(identify.structures())  # doctest: +NORMALIZE_WHITESPACE
    ['linear', 'bias', 'friction', 'dead-zone', 'stiction', 'second-order', 'asymmetric-gain', 'drive-limit',
     'current-limit', 'two-mass', 'two-mass-load']
    >>> identify.structures()["friction"].param_names
    ('a', 'b', 'friction', 'bias')
    """
    return {s.name: s for s in REGISTERED if s.in_default or not in_default}


register_structures(structures)     # the bench builds a named structure's plant (fake://) from this registry


def structure(name: str | ModelStructure) -> ModelStructure:
    """The registered structure called ``name`` (a structure is returned as it is)."""
    if isinstance(name, ModelStructure):
        return name
    found = structures()
    if name not in found:
        raise ParameterError(f"structure must be one of {list(found)}, got {name!r}")
    return found[name]


def structure_fitted(param_names: Sequence[str]) -> ModelStructure:
    """The registered structure whose parameters are exactly ``param_names`` (in any order).

    What an :class:`identify.Estimate` made without naming its structure belongs to (every
    estimator names it; this is for estimates a user makes by hand).

    Raises
    ------
    ParameterError
        No registered structure fits exactly these parameters: name the structure.
    """
    names = set(param_names)
    found = [s for s in REGISTERED if set(s.param_names) == names]
    if not found:
        known = ", ".join(f"{s.name} {list(s.param_names)}" for s in REGISTERED)
        raise ParameterError(f"structure must be given for the parameters {list(param_names)}: no registered "
                             f"structure fits exactly them ({known})")
    return found[0]


def structure_of(method: str, param_names: tuple[str, ...]) -> ModelStructure:
    """The structure an estimate of ``method`` with fitted ``param_names`` belongs to, in a file of the
    first format (which did not record it).

    Placed by what was fitted: a dead zone or friction (``oe-friction``), a bias, else the linear motor.
    """
    if method == "oe-friction":
        return structure("dead-zone" if "dead_zone" in param_names else
                         "stiction" if "static_friction" in param_names else "friction")
    for s in REGISTERED:
        if s.method == method and set(s.param_names) == set(param_names):
            return s
    return structure("bias" if "bias" in param_names else "linear")
