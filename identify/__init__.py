"""identify: estimators of a and b from a Recording (never from a rig)."""
from .closed_loop import fit_reference_iv
from .design import DesignPoint, SineDesign, design_sine, predicted_stderr
from .errors import NotIdentifiableError
from .estimate import Estimate
from .friction import fit_output_error_friction
from .instrumental import fit_instrumental_variables
from .methods import DEFAULT_METHOD, available_methods, fit, method_function
from .output_error import fit_output_error
from .regression import fit_euler_ls, fit_zoh_ls
from .uncertainty import CramerRaoBound, cramer_rao_bound
from .validation import ValidationReport, fit_percent, nrmse_fit, simulated_speed, validate

__all__ = ["NotIdentifiableError", "Estimate", "DEFAULT_METHOD", "available_methods", "fit", "method_function",
           "fit_output_error", "fit_instrumental_variables", "fit_reference_iv", "fit_output_error_friction",
           "fit_euler_ls", "fit_zoh_ls", "CramerRaoBound", "cramer_rao_bound",
           "design_sine", "predicted_stderr", "DesignPoint", "SineDesign",
           "fit_percent", "nrmse_fit", "simulated_speed", "ValidationReport", "validate"]
