"""identify: estimators of a and b from a Recording (never from a rig).

The names below are loaded on first use (PEP 562), so ``import identify`` and the command
line's ``--help`` do not pay for scipy's optimisers and filters until a fit needs them.
"""
from __future__ import annotations

from motorsim.lazy import lazy_attributes

#: public name -> the module of this package that defines it
_WHERE = {
    "NotIdentifiableError": "errors", "Estimate": "estimate",
    "SelectionReport": "default.selection_report", "CandidateReport": "default.selection_report",
    "structures": "model_structures", "structure": "model_structures", "ModelStructure": "model_structures",
    "DEFAULT_METHOD": "methods", "available_methods": "methods", "fit": "methods", "method_function": "methods",
    "method_options": "methods", "option_declarations": "methods", "check_options": "methods",
    "EstimatorOption": "estimators", "Estimator": "estimators", "estimator": "methods",
    "fit_output_error": "fits.output_error", "fit_instrumental_variables": "fits.instrumental",
    "fit_output_error_friction": "fits.friction", "fit_euler_ls": "fits.regression", "fit_zoh_ls": "fits.regression",
    "CramerRaoBound": "checks.uncertainty", "cramer_rao_bound": "checks.uncertainty",
    "fit_reference_iv": "fits.closed_loop", "fit_prediction_error": "fits.prediction_error",
    "feedback_evidence": "default.feedback",
    "design_sine": "checks.design", "predicted_stderr": "checks.design", "DesignPoint": "checks.design",
    "SineDesign": "checks.design",
    "design_multisine": "checks.design", "MultisineDesign": "checks.design",
    "fit_percent": "checks.validation", "nrmse_fit": "checks.validation", "simulated_speed": "checks.validation",
    "ValidationReport": "checks.validation", "validate": "checks.validation",
    "FrequencyResponse": "frequency.frequency_estimate", "frequency_response": "frequency.frequency_estimate",
    "zoh_speed_response": "frequency.frequency_estimate", "ModelResponse": "frequency.frequency_estimate",
    "BestLinearApproximation": "frequency.best_linear", "best_linear_approximation": "frequency.best_linear",
    "fit_frequency_response": "frequency.frequency_fit",
    "feedforward_constants": "feedforward", "FeedforwardConstants": "feedforward",
    "BatchFit": "fits.batch", "BATCHED_METHODS": "fits.batch", "fit_batch": "fits.batch",
    "fit_output_error_batch": "fits.batch",
    "output_error_batchable": "fits.batch",
}

__all__ = list(_WHERE)


__getattr__, __dir__ = lazy_attributes(__name__, exports={name: f".{module}" for name, module in _WHERE.items()})
