"""identify: estimators of a and b from a Recording (never from a rig)."""
from .errors import NotIdentifiableError
from .estimate import Estimate
from .methods import DEFAULT_METHOD, available_methods, fit
from .regression import fit_euler_ls, fit_zoh_ls
from .uncertainty import CramerRaoBound, cramer_rao_bound
from .validation import ValidationReport, fit_percent, nrmse_fit, simulated_speed, validate

__all__ = ["NotIdentifiableError", "Estimate", "DEFAULT_METHOD", "available_methods", "fit",
           "fit_euler_ls", "fit_zoh_ls", "CramerRaoBound", "cramer_rao_bound",
           "fit_percent", "nrmse_fit", "simulated_speed", "ValidationReport", "validate"]
