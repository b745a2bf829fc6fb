"""identify: estimators of a and b from a Recording (never from a rig).

The names below are loaded on first use (PEP 562), so ``import identify`` and the command
line's ``--help`` do not pay for scipy's optimisers and filters until a fit needs them.
"""
from __future__ import annotations

from motorsim.lazy import lazy_attributes, moved_modules

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

#: The modules that moved into a subpackage (the estimators to ``fits``, the default's selection to ``default``, the
#: uncertainty and checks to ``checks``, the frequency view to ``frequency``), by their earlier names: ``import
#: identify.selection`` gives ``identify.default.selection`` itself.  The comparison of candidates moved back to the
#: top, where the estimators' own delay search, the checks and the default share it: ``identify.default.comparison``
#: is ``identify.comparison``.
MOVED_MODULES = {
    "asymmetry": "fits.asymmetry", "batch": "fits.batch", "batch_output_error": "fits.batch_output_error",
    "closed_loop": "fits.closed_loop", "drive_limit": "fits.drive_limit", "electrical": "fits.electrical",
    "friction": "fits.friction", "friction_kernel": "fits.friction_kernel",
    "friction_response": "fits.friction_response", "friction_solver": "fits.friction_solver",
    "instrumental": "fits.instrumental", "output_error": "fits.output_error",
    "prediction_error": "fits.prediction_error", "recursive": "fits.recursive", "regression": "fits.regression",
    "sensitivity": "fits.sensitivity", "start": "fits.start", "stiction": "fits.stiction",
    "structure_fit": "fits.structure_fit", "variable_projection": "fits.variable_projection",
    "zoh_response": "fits.zoh_response", "consistency": "default.consistency",
    "evidence": "default.evidence", "feedback": "default.feedback", "selection": "default.selection",
    "selection_report": "default.selection_report", "causality": "checks.causality", "design": "checks.design",
    "encoder_bootstrap": "checks.encoder_bootstrap", "outliers": "checks.outliers", "screening": "checks.screening",
    "uncertainty": "checks.uncertainty", "validation": "checks.validation", "best_linear": "frequency.best_linear",
    "frequency_estimate": "frequency.frequency_estimate", "frequency_fit": "frequency.frequency_fit",
    "current_limit": "fits.current_limit", "limit_response": "fits.limit_response",
    "default.comparison": "comparison",
}
moved_modules(__name__, MOVED_MODULES)
