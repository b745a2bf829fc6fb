"""Controllers designed from a model: their gains, their predicted closed loop, the references they track.

A controller is designed once, in floating point, from the numbers of a motor model
(:class:`PlantModel`: ``a``, ``b``, ``friction``, ``bias``, ``input_delay``,
``sample_period``, ``counts_per_rev``; built from an identified estimate, a
:class:`~motorsim.plant.Motor` or plain numbers).  The design ends in a handful of
integer gains (Q16: a gain ``G`` stands for ``G / 2**16``), and the per-sample step
uses integers only: that step, shared with the firmware, and its integer units are
:mod:`motorsim.fixed_point` (:class:`~motorsim.fixed_point.ControlLoop`, which
:meth:`Controller.start` returns).

Exact model of the measured speed
---------------------------------
With ``e = exp(-a h)`` and the ZOH coefficients ``g, p, q`` of :func:`~motorsim.plant.zoh_matrices`,
the averaged speed ``y_k = (angle_k - angle_{k-1}) / h`` obeys exactly::

    y_{k+1} = e y_k + beta1 v_{k-D} + beta2 v_{k-D-1},   beta1 = q / h,  beta2 = (p g - e q) / h,

``beta1 + beta2 = g``, where ``v = u + (bias - friction sign(omega)) / b`` is the drive and
``D`` the input delay.  :meth:`PlantModel.speed_transfer_function` is this model in counts
per sample; every controller's :meth:`~Controller.predict` closes the loop on it with
python-control (``feedback``, ``forced_response``), delay included, using the quantised gains.

Controllers
-----------
:class:`OneStepMPC` (``mpc``), :class:`PISpeed` (``pi``, optionally with feedforward),
:class:`PositionPD` (``position``), :class:`Feedforward` (``feedforward``), :class:`LQRSpeed` (``lqr``),
:class:`LQRSpeedIntegral` (``lqr-integral``, with the speed error's integral in the state) and
:class:`LQRPosition` (``lqr-position``): LQR on the model with the input delay in the state.
The pole-placement designs (``pi``, ``position``) keep ``min_phase_margin`` on the exact model,
input delay included (:meth:`Controller.margins`), lengthening a time constant that cannot.

A model with an electrical time constant (:attr:`PlantModel.electrical_time_constant`, the
``second-order`` structure ``b / ((s + a)(tau_e s + 1))``): every design is made on its first-order
part (the step feeds back the speed and past duties only), and judged on the full plant, exact with
its delay (:meth:`PlantModel.speed_transfer_function`): the margins, the stability verdict, the
prediction and the robustness draws.  ``pi`` and ``position`` keep ``min_phase_margin`` there; a
design unstable there is refused (:class:`UnstableDesignError`), and one whose phase margin the
electrical pole cuts by more than :data:`~motorsim.control.pole_placement.ELECTRICAL_PHASE_COST`
degrees, to below :data:`MIN_PHASE_MARGIN`, is warned of (:class:`DesignLimitWarning`).
:class:`ClosedLoopExperiment` asks a rig to run one of them against a :class:`Reference`.

Layout
------
One module per part, every public name re-exported here (``from motorsim.control import X``):
:mod:`~motorsim.control.model` (:class:`PlantModel`), :mod:`~motorsim.control.references`
(:class:`Reference`, :func:`parse_reference`), :mod:`~motorsim.control.base` (:class:`Controller`,
:class:`Prediction`), one module per controller family (:mod:`~motorsim.control.mpc`,
:mod:`~motorsim.control.pi`, :mod:`~motorsim.control.position`, :mod:`~motorsim.control.feedforward`,
:mod:`~motorsim.control.lqr`, with :mod:`~motorsim.control.pole_placement` shared by ``pi`` and
``position``), :mod:`~motorsim.control.design` (:data:`CONTROLLERS`, :func:`design_controller`) and
:mod:`~motorsim.control.experiment` (:class:`ClosedLoopExperiment`, :func:`tracking_error`).
"""
from __future__ import annotations

from ..fixed_point import (  # noqa: F401  (the step's names, still resolved here)
    MAX_REFERENCE,
    SPEED_REFERENCE_BITS,
    SPEED_REFERENCE_LSB,
    ControlLoop,
    ReferenceWords,
    gain_value,
    quantise_gain,
    reference_values,
)
from ..lazy import lazy_attributes
from .base import Controller, Prediction
from .design import CONTROLLERS, design_controller, settings_from
from .experiment import ClosedLoopExperiment, tracking_error
from .feedforward import Feedforward, feedforward_gains
from .lqr import INTEGRAL_WEIGHT, LQRPosition, LQRSpeed, LQRSpeedIntegral
from .model import PlantModel
from .mpc import OneStepMPC
from .pi import PISpeed
from .pole_placement import MIN_PHASE_MARGIN, DesignLimitWarning, UnstableDesignError
from .position import PositionPD
from .references import Reference, parse_reference

__all__ = ["PlantModel", "Reference", "parse_reference", "Controller", "OneStepMPC", "PISpeed", "PositionPD",
           "Feedforward", "LQRSpeed", "LQRSpeedIntegral", "LQRPosition", "Prediction", "ClosedLoopExperiment",
           "CONTROLLERS", "design_controller", "tracking_error", "feedforward_gains", "settings_from",
           "DesignLimitWarning", "UnstableDesignError", "MIN_PHASE_MARGIN", "INTEGRAL_WEIGHT"]

# names of the fixed-point step this package no longer holds: old imports warn for one release
__getattr__, __dir__ = lazy_attributes(__name__, moved=dict.fromkeys(("GAIN_BITS", "GAIN_ORDER", "gains_from_wire"),
                                                                       "motorsim.fixed_point"))
