"""``Estimate``: the result every estimator returns."""
from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Mapping

import numpy as np
from scipy import stats

if TYPE_CHECKING:
    import control

__all__ = ["Estimate", "json_ready"]


@dataclasses.dataclass(frozen=True, eq=False)
class Estimate:
    """Identified parameters of ``d omega/dt + a omega = b u``, with their quality.

    Attributes
    ----------
    method : str
        Name of the estimator (``motorid identify --method``).
    a : float
        Pole in 1/s.
    b : float
        Gain in (rad/s^2) per input unit.
    n_samples : int
        Samples used (regression rows, or fitted output samples).
    sample_period : float
        Nominal sample period of the data in s.
    residual_rms : float
        RMS of the estimator's own residual, in ``residual_unit``.
    fit_percent : float
        NRMSE fit in % of the model's simulated speed against the measured speed,
        ``100 (1 - ||y - y_sim|| / ||y - mean(y)||)`` (100 is perfect).
    covariance : ndarray, shape (p, p), optional
        Covariance of the parameters named in ``param_names``.
    param_names : tuple of str
        Order of the parameters in ``covariance``; starts with ``"a", "b"``.
    extra : mapping of str to float or int
        Further parameters: ``friction`` (Coulomb friction ``c``) and ``bias`` (constant
        acceleration ``d``) in rad/s^2, ``dead_zone`` in input units, ``input_delay``
        in samples (an int).
    residual_unit : str
        Unit of ``residual_rms``.
    input_unit : str
        Unit of the input ``u`` (``duty`` on the bench).
    covariance_method : str
        How ``covariance`` was computed: ``"gauss-newton"`` (white residuals assumed) or
        ``"newey-west"`` (a sandwich that allows correlated residuals), see
        :func:`identify.uncertainty.robust_covariance`; ``""`` when not said.
    """

    method: str
    a: float
    b: float
    n_samples: int
    sample_period: float
    residual_rms: float
    fit_percent: float
    covariance: np.ndarray | None = None
    param_names: tuple[str, ...] = ("a", "b")
    extra: Mapping[str, float | int] = dataclasses.field(default_factory=dict)
    residual_unit: str = "rad/s"
    input_unit: str = "duty"
    covariance_method: str = ""

    def __post_init__(self):
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            if cov.shape != (len(self.param_names),) * 2:
                raise ValueError(f"covariance must have shape {(len(self.param_names),) * 2}, got {cov.shape}")
            cov.setflags(write=False)
            object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "extra", dict(self.extra))

    @property
    def static_gain(self) -> float:
        """Steady-state speed per input unit, ``b / a``."""
        return self.b / self.a

    @property
    def time_constant(self) -> float:
        """``1 / a`` in s."""
        return 1.0 / self.a

    def value(self, name: str) -> float | int:
        """The estimate of parameter ``name`` (``a``, ``b`` or a key of ``extra``)."""
        if name in ("a", "b"):
            return getattr(self, name)
        if name in self.extra:
            return self.extra[name]
        raise KeyError(f"name must be one of {['a', 'b', *self.extra]}, got {name!r}")

    def stderr(self) -> dict[str, float]:
        """Standard error of each parameter in ``param_names`` (nan without a covariance)."""
        if self.covariance is None:
            return {n: math.nan for n in self.param_names}
        return {n: float(math.sqrt(max(v, 0.0))) for n, v in zip(self.param_names, np.diag(self.covariance))}

    def confidence_interval(self, level: float = 0.95) -> dict[str, tuple[float, float]]:
        """Two-sided normal-approximation interval per parameter, ``value +- z sigma``.

        Parameters
        ----------
        level : float
            Coverage, in (0, 1) (default 0.95).

        Returns
        -------
        dict of str to (float, float)
            ``(low, high)`` per name in ``param_names``.

        Examples
        --------
        >>> import numpy as np
        >>> est = Estimate(method="oe", a=25.0, b=3.0, n_samples=1000, sample_period=0.005,
        ...                residual_rms=1e-4, fit_percent=99.9, covariance=np.diag([0.01, 1e-4]))
        >>> for name, (low, high) in est.confidence_interval(0.95).items():
        ...     print(f"{name}: [{low:.3f}, {high:.3f}]")
        a: [24.804, 25.196]
        b: [2.980, 3.020]
        """
        if not 0 < level < 1:
            raise ValueError(f"level must be in (0, 1), got {level!r}")
        z = stats.norm.ppf(0.5 + level / 2)
        return {n: (self.value(n) - z * s, self.value(n) + z * s) for n, s in self.stderr().items()}

    def transfer_function(self) -> control.TransferFunction:
        """``b / (s + a)`` from input to speed."""
        import control
        return control.tf([self.b], [1.0, self.a])

    def to_dict(self) -> dict:
        """JSON-ready summary (``motorid identify --json``)."""
        out = {"method": self.method, "a": self.a, "b": self.b, "static_gain": self.static_gain,
               "fit_percent": self.fit_percent, "n_samples": self.n_samples,
               "sample_period": self.sample_period, "residual_rms": self.residual_rms,
               "residual_unit": self.residual_unit, "input_unit": self.input_unit}
        if self.covariance_method:
            out["covariance_method"] = self.covariance_method
        out.update(self.extra)
        se = self.stderr()
        ci = self.confidence_interval(0.95)
        for name in self.param_names:
            out[f"{name}_stderr"] = se[name]
            out[f"{name}_ci95"] = list(ci[name])
        return json_ready(out)


def json_ready(value):
    """``value`` with every non-finite float (nan, inf) replaced by None, recursively.

    JSON has no nan; ``json.dumps`` would write the invalid token ``NaN``.

    >>> json_ready({"a": float("nan"), "b": [1.0, float("inf")]})
    {'a': None, 'b': [1.0, None]}
    """
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    return value
