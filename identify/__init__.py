"""identify: estimators of a and b from a Recording (never from a rig).

The names below are loaded on first use (PEP 562), so ``import identify`` and the command
line's ``--help`` do not pay for scipy's optimisers and filters until a fit needs them.
"""
from __future__ import annotations

from motorsim.lazy import lazy_attributes

#: public name -> the module of this package that defines it
_WHERE = {
    "NotIdentifiableError": "errors", "Estimate": "estimate",
    "SelectionReport": "selection_report", "CandidateReport": "selection_report",
    "structures": "model_structures", "structure": "model_structures", "ModelStructure": "model_structures",
    "DEFAULT_METHOD": "methods", "available_methods": "methods", "fit": "methods", "method_function": "methods",
    "method_options": "methods", "option_declarations": "methods", "check_options": "methods",
    "EstimatorOption": "estimators", "Estimator": "estimators", "estimator": "methods",
    "fit_output_error": "output_error", "fit_instrumental_variables": "instrumental",
    "fit_output_error_friction": "friction", "fit_euler_ls": "regression", "fit_zoh_ls": "regression",
    "CramerRaoBound": "uncertainty", "cramer_rao_bound": "uncertainty",
    "fit_reference_iv": "closed_loop", "fit_prediction_error": "prediction_error",
    "feedback_evidence": "feedback",
    "design_sine": "design", "predicted_stderr": "design", "DesignPoint": "design", "SineDesign": "design",
    "design_multisine": "design", "MultisineDesign": "design",
    "fit_percent": "validation", "nrmse_fit": "validation", "simulated_speed": "validation",
    "ValidationReport": "validation", "validate": "validation",
    "FrequencyResponse": "frequency_estimate", "frequency_response": "frequency_estimate",
    "zoh_speed_response": "frequency_estimate", "ModelResponse": "frequency_estimate",
    "BestLinearApproximation": "best_linear", "best_linear_approximation": "best_linear",
    "fit_frequency_response": "frequency_fit",
    "feedforward_constants": "feedforward", "FeedforwardConstants": "feedforward",
    "BatchFit": "batch", "BATCHED_METHODS": "batch", "fit_batch": "batch", "fit_output_error_batch": "batch",
    "output_error_batchable": "batch",
}

__all__ = list(_WHERE)


__getattr__, __dir__ = lazy_attributes(__name__, exports={name: f".{module}" for name, module in _WHERE.items()})
