"""``Estimate``: the result every estimator returns, and the model it describes.

An estimate carries everything needed to rebuild the identified model: ``a``, ``b``, the
covariance, the input delay, friction, bias and dead zone (``extra``), the sample period,
the units and the method.  It gives that model back as a python-control transfer function
(:meth:`Estimate.transfer_function`: the linear part, with its delay exact in discrete time),
as a python-control nonlinear system (:meth:`Estimate.io_system`: everything, exact at the
sample instants), as a :class:`motorsim.plant.Motor` (:meth:`Estimate.motor`), and as JSON
(:meth:`Estimate.to_json`, :meth:`Estimate.from_json`; ``motorid identify --save``).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import statistics
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from motorsim.checks import ParameterError, ParameterTypeError, check_int, check_real
from motorsim.plant import Motor, simulate

if TYPE_CHECKING:
    import control

__all__ = ["Estimate", "json_ready", "file_sha256", "with_data_files", "ESTIMATE_FORMAT"]

#: The ``format`` field of :meth:`Estimate.to_json`.
ESTIMATE_FORMAT = "motorid estimate v1"


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
    data_files : tuple of (str, str)
        The recordings fitted, as ``(path, sha256 hex digest)`` (empty unless set, e.g. by
        ``motorid identify --save``).
    selection : mapping, optional
        How the default estimator chose this model (:func:`identify.selection.fit_selected`):
        every candidate (structure, input delay, fit, score), the chosen one, the best, the
        runner-up, whether the choice was ``clear`` and the ``doubt`` line; None when a method
        was named.
    model_range : mapping of str to (float, float)
        For ``a`` and ``b`` when the selection found candidates it cannot rule out that disagree:
        the range of their values (``inf`` when a static gain fits as well).
        :meth:`confidence_interval` is the union of the fit's own interval and this range.
    notes : tuple of str
        What the data could not answer, one line each (the choice's doubt, saturation, too few
        encoder counts, an input too slow for ``a``, a parameter left without an interval).
    covariance_method : str
        How ``covariance`` was computed (``+model-spread`` when the selection widened it to cover
        the candidates the data cannot rule out): ``"gauss-newton"`` (white residuals assumed),
        ``"newey-west"`` (a sandwich that allows correlated residuals, see
        :func:`identify.uncertainty.robust_covariance`), ``"encoder-bootstrap"`` (``oe`` on a
        coarse encoder: refits of the model re-quantised at other encoder phases) or
        ``"linearised-encoder-bootstrap"`` (``oe-friction`` when rounding dominates the
        residuals: one Gauss–Newton step per phase), ``"instrumental-variables"`` (``iv``: the
        IV estimator's sandwich) or ``"regression"`` (``euler-ls``, ``zoh-ls``: the least-squares
        covariance of the speed regression; the regression's own bias, from the differenced
        speed and for ``euler-ls`` the Euler step, is not in it, so its interval need not cover
        the motor's ``a`` and ``b``); ``""`` when not said.
    input_limit : float, optional
        Largest input magnitude the drive accepts, in ``input_unit`` (255 for duty on the bench,
        the recording's ``input_limit`` for a lab's file); None when unknown. Control design
        warns when a controller needs more.
    speed_unit : str
        The speed unit of the data the model was fitted to (``rpm``, ...; the recording's
        ``speed_unit``), for showing results in it; every value here stays in rad/s.
    speed_residuals : tuple of ndarray, optional
        The fit's speed residual (measured minus model, rad/s) on each recording it was fitted on,
        in the order given, row by row exactly as :func:`identify.validation.model_output` gives it
        (``nan`` where undefined): kept by ``oe`` so the outlier check after the fit need not
        simulate the model again.  In memory only (not in JSON); None when not kept.
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
    data_files: tuple[tuple[str, str], ...] = ()
    covariance_method: str = ""
    selection: Mapping[str, Any] | None = None
    notes: tuple[str, ...] = ()
    model_range: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    input_limit: float | None = None
    speed_unit: str = "rad/s"
    speed_residuals: tuple[np.ndarray, ...] | None = dataclasses.field(default=None, repr=False)

    def __post_init__(self):
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            if cov.shape != (len(self.param_names),) * 2:
                raise ParameterError(f"covariance must have shape {(len(self.param_names),) * 2}, got {cov.shape}")
            cov.setflags(write=False)
            object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "extra", dict(self.extra))
        object.__setattr__(self, "data_files", tuple((str(p), str(h)) for p, h in self.data_files))
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))
        object.__setattr__(self, "model_range", {str(k): (float(lo), float(hi))
                                                 for k, (lo, hi) in dict(self.model_range).items()})
        if self.input_limit is not None:
            limit = float(self.input_limit)
            if not (math.isfinite(limit) and limit > 0):
                raise ParameterError(f"input_limit must be a finite number > 0 {self.input_unit} or None, "
                                 f"got {self.input_limit!r}")
            object.__setattr__(self, "input_limit", limit)

    def _repr_html_(self) -> str:
        """A table of the parameters with their standard errors and 95 % intervals (notebooks)."""
        import html
        se = self.stderr()
        ci = self.confidence_interval(0.95)
        units = {"a": "1/s", "b": f"(rad/s²)/{self.input_unit}", "friction": "rad/s²", "bias": "rad/s²",
                 "dead_zone": self.input_unit, "input_delay": "samples"}
        rows = []
        for name in ("a", "b", *self.extra):
            err = se.get(name, math.nan)
            lo, hi = ci.get(name, (math.nan, math.nan))
            cells = [name, f"{self.value(name):.6g}", units.get(name, ""),
                     f"{err:.2g}" if math.isfinite(err) else "",
                     f"[{lo:.6g}, {hi:.6g}]" if math.isfinite(err) else ""]
            rows.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
        caption = (f"{html.escape(self.method)}: fit {self.fit_percent:.2f} %, {self.n_samples} samples at "
                   f"{self.sample_period:.6g} s")
        if self.input_limit is not None:
            caption += f", input limit ±{self.input_limit:g} {html.escape(self.input_unit)}"
        return ("<table><caption>" + caption + "</caption><tr><th>parameter</th><th>value</th><th>unit</th>"
                "<th>stderr</th><th>95 % CI</th></tr>" + "".join(rows) + "</table>")

    @property
    def input_delay(self) -> int:
        """Input delay in samples (``extra["input_delay"]``, 0 when the method has none)."""
        return int(self.extra.get("input_delay", 0))

    def __repr__(self) -> str:
        extra = "".join(f", {k}={v:.6g}" for k, v in self.extra.items())
        return (f"Estimate(method={self.method!r}, a={self.a:.6g}, b={self.b:.6g}{extra}, "
                f"sample_period={self.sample_period:.6g}, fit_percent={self.fit_percent:.4g}, "
                f"n_samples={self.n_samples})")

    def __str__(self) -> str:
        """Value, standard error and 95 % interval of each parameter, then the fit (plain floats)."""
        se = self.stderr()
        ci = self.confidence_interval(0.95)
        delay_s = self.input_delay * self.sample_period
        units = {"a": "1/s", "b": f"(rad/s^2)/{self.input_unit}", "friction": "rad/s^2", "bias": "rad/s^2",
                 "dead_zone": self.input_unit, "input_delay": f"samples ({delay_s:.6g} s)"}

        def line(name: str) -> str:
            text = f"{name:<11} {self.value(name):.6g} {units.get(name, '')}"
            if name in se and math.isfinite(se[name]):
                lo, hi = ci[name]
                text += f"   (stderr {se[name]:.2g})   95 % CI [{lo:.6g}, {hi:.6g}]"
            return text.rstrip()
        lines = [f"method      {self.method}", *(line(n) for n in ("a", "b", *self.extra)),
                 f"b/a         {self.static_gain:.6g} (rad/s)/{self.input_unit}",
                 f"fit         {self.fit_percent:.2f} % (NRMSE, simulated vs measured speed)",
                 f"residual    {self.residual_rms:.3g} {self.residual_unit} RMS",
                 f"samples     {self.n_samples} (sample period {self.sample_period:.6g} s)"]
        missing = self.missing_intervals()
        if missing:
            lines.append(f"note        no interval for {missing}")
        lines += [f"note        {n}" for n in self.notes]
        if self.input_limit is not None:
            lines.append(f"input limit +-{self.input_limit:g} {self.input_unit}")
        if self.covariance_method == "regression":
            lines.append(f"note        {self.method}'s intervals are its regression's and leave out its bias "
                         "(the differenced speed): they need not cover the motor's a and b; use oe")
        return "\n".join(lines)

    def missing_intervals(self) -> str:
        """Which parameters have no finite standard error, and why, in words ("" when all have one)."""
        se = self.stderr()
        names = [n for n in self.param_names if not math.isfinite(se[n])]
        if not names:
            return ""
        why = ("no covariance was computed" if self.covariance is None else
               "the data do not determine them (the information matrix is singular along them)")
        return f"{', '.join(names)}: {why}"

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

        Where the model selection left candidates it cannot rule out (:attr:`model_range`), the
        interval of ``a`` and ``b`` is the union of that one and their range.

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
            raise ParameterError(f"level must be in (0, 1), got {level!r}")
        z = statistics.NormalDist().inv_cdf(0.5 + level / 2)
        out = {n: (float(self.value(n) - z * s), float(self.value(n) + z * s)) for n, s in self.stderr().items()}
        for n, (lo, hi) in self.model_range.items():       # candidates the data cannot rule out: the union
            own = out.get(n, (math.nan, math.nan))
            out[n] = (min(lo, own[0]) if math.isfinite(own[0]) else lo,
                      max(hi, own[1]) if math.isfinite(own[1]) else hi)
        return out

    def transfer_function(self, form: str = "continuous", *, delay: str | None = None,
                          pade_order: int = 3) -> control.TransferFunction:
        """The linear part of the model, from ``duty`` (input unit) to ``speed`` (rad/s).

        Parameters
        ----------
        form : {"continuous", "discrete"}
            ``continuous``: ``b / (s + a)``.  ``discrete``: its exact zero-order-hold model at
            :attr:`sample_period`, ``z^-d (b/a)(1 - e) / (z - e)`` with ``e = exp(-a T)`` and
            the input delay ``d`` samples included exactly.
        delay : {None, "pade"}
            How the continuous form carries an input delay ``d > 0``: ``"pade"`` multiplies by a
            Padé approximation of ``exp(-s d T)`` of order ``pade_order``; None (the default)
            refuses, since ``b/(s + a)`` alone would drop the delay.
        pade_order : int
            Order of the Padé approximation (default 3).

        Returns
        -------
        control.TransferFunction
            Input named ``duty``, output ``speed``; ``dt`` is the sample period in the discrete form.
            Friction, bias and dead zone are not linear: :meth:`io_system` carries them.

        Raises
        ------
        ValueError
            For a delayed estimate in continuous form without ``delay="pade"``.

        Examples
        --------
        >>> est = Estimate(method="oe", a=25.0, b=3.0, n_samples=1000, sample_period=0.005,
        ...                residual_rms=1e-4, fit_percent=99.9, extra={"input_delay": 2})
        >>> tf = est.transfer_function("discrete")
        >>> tf.dt, tf.den[0][0].round(4).tolist()       # z^2 (z - e): the delay of 2 samples is kept
        (0.005, [1.0, -0.8825, 0.0, 0.0])
        """
        import control
        if form not in ("continuous", "discrete"):
            raise ParameterError(f"form must be 'continuous' or 'discrete', got {form!r}")
        if delay not in (None, "pade"):
            raise ParameterError(f"delay must be None or 'pade', got {delay!r}")
        names = {"inputs": "duty", "outputs": "speed"}
        d = self.input_delay
        if form == "discrete":
            e = math.exp(-self.a * self.sample_period)
            g = -self.b / self.a * math.expm1(-self.a * self.sample_period)
            return control.tf([g], [1.0, -e, *([0.0] * d)], self.sample_period, **names)
        tf = control.tf([self.b], [1.0, self.a], **names)
        if d == 0:
            return tf
        if delay is None:
            raise ParameterError(f"this estimate has an input delay of {d} samples ({d * self.sample_period:.6g} s), "
                             "which b/(s + a) cannot carry: use transfer_function('discrete') for the exact "
                             "model with z^-d, or delay='pade' for a continuous approximation")
        if not (isinstance(pade_order, int) and pade_order >= 1):
            raise ParameterError(f"pade_order must be an integer >= 1, got {pade_order!r}")
        num, den = control.pade(d * self.sample_period, pade_order)
        return control.tf(np.polymul(num, [self.b]), np.polymul(den, [1.0, self.a]), **names)

    def motor(self) -> Motor:
        """The identified model as a :class:`motorsim.plant.Motor` (friction, bias, dead zone, delay)."""
        return Motor(self.a, self.b, friction=float(self.extra.get("friction", 0.0)),
                     bias=float(self.extra.get("bias", 0.0)), dead_zone=float(self.extra.get("dead_zone", 0.0)),
                     input_delay=self.input_delay)

    def io_system(self, name: str = "motor") -> control.NonlinearIOSystem:
        """The full identified model as a discrete-time python-control system at :attr:`sample_period`.

        States ``angle`` (rad), ``speed`` (rad/s) and, with an input delay of ``d`` samples, the
        last ``d`` duties (``duty_1`` ... ``duty_d``, most recent first); input ``duty``;
        outputs ``speed`` and ``angle``.  Each step integrates the interval exactly as
        :func:`motorsim.plant.simulate` does: the zero-order-hold solution of the linear part,
        the dead zone applied to the delayed duty, and with Coulomb friction the event-by-event
        solution (zero crossings, sticking at rest while ``|b v + d| <= c``).  So
        ``control.input_output_response`` reproduces ``simulate`` at the sample instants to
        rounding; between samples the model says nothing (friction makes it non-linear in
        time, so no continuous-time system is exact).

        Parameters
        ----------
        name : str
            Name of the system.

        Returns
        -------
        control.NonlinearIOSystem
            ``dt`` is the sample period; the initial state ``[angle, speed, duty before ...]``.

        Examples
        --------
        >>> import control
        >>> est = Estimate(method="oe", a=25.0, b=3.0, n_samples=1000, sample_period=0.01,
        ...                residual_rms=1e-4, fit_percent=99.9)
        >>> res = control.input_output_response(est.io_system(), np.arange(5) * 0.01, np.full(5, 100.0))
        >>> res.outputs[0].round(3).tolist()             # speed, as motorsim.simulate gives it
        [0.0, 2.654, 4.722, 6.332, 7.585]
        """
        import control
        motor = dataclasses.replace(self.motor(), input_delay=0)
        d, h = self.input_delay, self.sample_period
        times = np.array([0.0, h])

        def update(t, x, u, params):
            applied = x[2 + d - 1] if d else u[0]
            traj = simulate(motor, np.array([applied, applied]), times, initial_speed=x[1], initial_angle=x[0])
            return np.array([traj.angle[1], traj.speed[1], u[0], *x[2:2 + d - 1]] if d else
                            [traj.angle[1], traj.speed[1]])

        def output(t, x, u, params):
            return np.array([x[1], x[0]])
        states = ["angle", "speed", *(f"duty_{k}" for k in range(1, d + 1))]
        return control.nlsys(update, output, inputs=["duty"], outputs=["speed", "angle"], states=states,
                             dt=h, name=name)

    def to_dict(self) -> dict:
        """JSON-ready summary (``motorid identify --json``)."""
        out = {"method": self.method, "a": self.a, "b": self.b, "static_gain": self.static_gain,
               "fit_percent": self.fit_percent, "n_samples": self.n_samples,
               "sample_period": self.sample_period, "residual_rms": self.residual_rms,
               "residual_unit": self.residual_unit, "input_unit": self.input_unit, "input_limit": self.input_limit,
               "speed_unit": self.speed_unit}
        if self.covariance_method:
            out["covariance_method"] = self.covariance_method
        out.update(self.extra)
        se = self.stderr()
        ci = self.confidence_interval(0.95)
        for name in self.param_names:
            out[f"{name}_stderr"] = se[name]
            out[f"{name}_ci95"] = list(ci[name])
        missing = self.missing_intervals()
        out["notes"] = list(self.notes) + ([f"no interval for {missing}"] if missing else [])
        if self.selection is not None:
            out["selection"] = self.selection
        if self.model_range:
            out["model_range"] = {k: list(v) for k, v in self.model_range.items()}
        return json_ready(out)

    def to_json(self, *, indent: int | None = 2) -> str:
        """Everything needed to rebuild the estimate, as a JSON document (:meth:`from_json` reads it).

        The fields: ``format`` (``motorid estimate v1``), ``method``, ``a``, ``b``, ``extra``
        (friction, bias, dead zone, ``input_delay``), ``param_names`` and ``covariance`` (rows in
        that order, null where not finite), ``sample_period`` (s), ``units``, ``n_samples``,
        ``fit_percent``, ``residual_rms``, ``data_files`` (path and sha256 of each recording) and
        ``feedforward`` (kS, kV, kA, k0 with intervals, :mod:`identify.feedforward`; derived, not read back).
        ``input_limit`` (the largest input the drive accepts, in the input unit; null when unknown).

        Parameters
        ----------
        indent : int or None
            Indentation of the JSON text (None: one line).

        Examples
        --------
        >>> est = Estimate(method="oe", a=25.0, b=3.0, n_samples=1000, sample_period=0.005,
        ...                residual_rms=1e-4, fit_percent=99.9, covariance=np.diag([0.01, 1e-4]))
        >>> Estimate.from_json(est.to_json()).covariance.tolist()
        [[0.01, 0.0], [0.0, 0.0001]]
        """
        doc = {"format": ESTIMATE_FORMAT, "method": self.method, "a": self.a, "b": self.b, "extra": self.extra,
               "param_names": list(self.param_names),
               "covariance": None if self.covariance is None else self.covariance.tolist(),
               "sample_period": self.sample_period,
               "units": {"a": "1/s", "b": f"(rad/s^2)/{self.input_unit}", "input": self.input_unit,
                         "friction": "rad/s^2", "bias": "rad/s^2", "dead_zone": self.input_unit,
                         "input_delay": "samples", "sample_period": "s", "residual_rms": self.residual_unit,
                         "speed": self.speed_unit},
               "input_limit": self.input_limit,
               "n_samples": self.n_samples, "fit_percent": self.fit_percent, "residual_rms": self.residual_rms,
               "data_files": [{"path": p, "sha256": h} for p, h in self.data_files],
               "covariance_method": self.covariance_method, "notes": list(self.notes)}
        if self.selection is not None:
            doc["selection"] = self.selection
        if self.model_range:
            doc["model_range"] = {k: list(v) for k, v in self.model_range.items()}
        from .feedforward import feedforward_constants
        doc["feedforward"] = feedforward_constants(self).to_dict()     # kS, kV, kA: read back from a, b
        return json.dumps(json_ready(doc), indent=indent)

    @classmethod
    def from_json(cls, text: str | bytes) -> "Estimate":
        """The estimate :meth:`to_json` wrote (a JSON document, or the path of a file holding one).

        Parameters
        ----------
        text : str or bytes
            JSON text (bytes: UTF-8), or a path to a ``.json`` file.

        Raises
        ------
        motorsim.checks.ParameterError
            (a ``ValueError``) When the document is not a motorid estimate (``format``
            missing or another, invalid or binary JSON, nested too deep, over
            :data:`MAX_ESTIMATE_BYTES`, a number that is not finite where one must be), naming
            the field; :class:`motorsim.checks.ParameterTypeError` (also a ``TypeError``) for a
            field of the wrong kind (``"a": true``, ``"extra": []``, ``input_delay: 1.5``).
        """
        if not isinstance(text, (str, bytes)):
            raise ParameterTypeError(f"text must be JSON text or the path of a JSON file, got {type(text).__name__}")
        if isinstance(text, bytes):
            text = _decoded(text, "text")
        if not text.lstrip().startswith("{") and os.path.exists(text):
            from motorsim.files import read_input_bytes
            text = _decoded(read_input_bytes(text, what="model", max_bytes=MAX_ESTIMATE_BYTES), text)
        if len(text) > MAX_ESTIMATE_BYTES:
            raise ParameterError(f"an estimate must be at most {MAX_ESTIMATE_BYTES} characters of JSON, "
                                 f"got {len(text)}")
        try:
            doc = json.loads(text, parse_constant=_no_constant)
        except json.JSONDecodeError as exc:
            raise ParameterError(f"an estimate must be a JSON document, got invalid JSON ({exc})") from None
        except RecursionError:
            raise ParameterError("an estimate must be a JSON document of a few levels, got one nested "
                                 "too deep to read") from None
        if not isinstance(doc, dict) or doc.get("format") != ESTIMATE_FORMAT:
            found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
            raise ParameterError(f"an estimate must have format {ESTIMATE_FORMAT!r}, got {found!r}")
        return cls(**_estimate_fields(doc))


#: The largest saved estimate read, in bytes (one is about 2 kB).
MAX_ESTIMATE_BYTES = 1 << 20


def _decoded(data: bytes, name: str) -> str:
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ParameterError(f"an estimate must be UTF-8 JSON text; {name} is binary ({exc.reason} at byte "
                             f"{exc.start})") from None


def _no_constant(name: str) -> float:
    raise ParameterError(f"an estimate must hold finite numbers or null, got {name}")


def _estimate_fields(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :class:`Estimate` from a saved document, each field checked."""
    def field(name: str, kind: type | tuple[type, ...], default: Any = ...) -> Any:
        if name not in doc:
            if default is ...:
                raise ParameterError(f"an estimate must have the field {name!r}")
            return default
        value = doc[name]
        if not isinstance(value, kind) or isinstance(value, bool) and bool not in (kind if isinstance(kind, tuple)
                                                                                   else (kind,)):
            raise ParameterTypeError(f"estimate field {name!r} must be {_kind_name(kind)}, got {value!r:.80}")
        return value

    def real(name: str, value: Any, *, finite: bool = True) -> float:
        if value is None and not finite:
            return math.nan
        return check_real(f"estimate field {name!r}", value, finite=finite)

    names = field("param_names", list, ["a", "b"])
    if not all(isinstance(n, str) for n in names):
        raise ParameterTypeError(f"estimate field 'param_names' must be a list of names, got {names!r:.80}")
    cov = field("covariance", (list, type(None)), None)
    if cov is not None:
        if len(cov) != len(names) or not all(isinstance(row, list) and len(row) == len(names) for row in cov):
            raise ParameterError(f"estimate field 'covariance' must be {len(names)} rows of {len(names)} numbers, "
                                 f"got {cov!r:.80}")
        cov = np.array([[real("covariance", x, finite=False) for x in row] for row in cov])
    extra: dict[str, float | int] = {}
    for key, value in field("extra", dict, {}).items():
        if key == "input_delay":
            extra[key] = check_int("estimate field 'extra.input_delay'", value, lo=0, allow_integral_float=False)
        else:
            extra[key] = real(f"extra.{key}", value, finite=False)
    units = field("units", dict, {})
    for key in ("residual_rms", "input", "speed"):
        if not isinstance(units.get(key, ""), str):
            raise ParameterTypeError(f"estimate field 'units.{key}' must be a string, got {units[key]!r:.80}")
    files = field("data_files", list, [])
    if not all(isinstance(f, dict) and isinstance(f.get("path"), str) and isinstance(f.get("sha256"), str)
               for f in files):
        raise ParameterTypeError(f"estimate field 'data_files' must be a list of {{path, sha256}}, got {files!r:.80}")
    return dict(method=field("method", str), a=real("a", field("a", (int, float))),
                b=real("b", field("b", (int, float))),
                n_samples=check_int("estimate field 'n_samples'", field("n_samples", int), lo=0),
                sample_period=check_real("estimate field 'sample_period'", field("sample_period", (int, float)),
                                         positive=True),
                residual_rms=real("residual_rms", field("residual_rms", (int, float, type(None)), None), finite=False),
                fit_percent=real("fit_percent", field("fit_percent", (int, float, type(None)), None), finite=False),
                covariance=cov, param_names=tuple(names), extra=extra,
                residual_unit=units.get("residual_rms", "rad/s"), input_unit=units.get("input", "duty"),
                data_files=tuple((f["path"], f["sha256"]) for f in files),
                covariance_method=field("covariance_method", str, ""),
                selection=field("selection", (dict, type(None)), None),
                notes=tuple(_strings("notes", field("notes", list, []))),
                model_range=_model_range(field("model_range", (dict, type(None)), None) or {}),
                input_limit=_input_limit(field("input_limit", (int, float, type(None)), None)),
                speed_unit=units.get("speed", "rad/s"))


def _input_limit(value: Any) -> float | None:
    if value is None:
        return None
    return check_real("estimate field 'input_limit'", value, positive=True)


def _strings(name: str, values: list) -> list[str]:
    if not all(isinstance(v, str) for v in values):
        raise ParameterTypeError(f"estimate field {name!r} must be a list of strings, got {values!r:.80}")
    return values


def _model_range(ranges: Mapping[str, Any]) -> dict[str, tuple[float, float]]:
    out = {}
    for key, pair in ranges.items():
        if not (isinstance(pair, list) and len(pair) == 2):
            raise ParameterTypeError(f"estimate field 'model_range.{key}' must be [low, high], got {pair!r:.80}")
        low, high = (math.nan if x is None else check_real(f"estimate field 'model_range.{key}'", x, finite=False)
                     for x in pair)
        out[key] = (low, high)
    return out


def _kind_name(kind: type | tuple[type, ...]) -> str:
    names = {int: "an integer", float: "a number", str: "a string", list: "a list", dict: "an object",
             type(None): "null"}
    kinds = kind if isinstance(kind, tuple) else (kind,)
    if float in kinds:
        kinds = tuple(k for k in kinds if k is not int)
    return " or ".join(names.get(k, k.__name__) for k in kinds)


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 hex digest of a file's bytes (the ``data_files`` of an estimate)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def with_data_files(estimate: Estimate, paths: Sequence[str | os.PathLike]) -> Estimate:
    """``estimate`` recording the paths and SHA-256 digests of the files it was fitted to."""
    return dataclasses.replace(estimate, data_files=tuple((os.fspath(p), file_sha256(p)) for p in paths))


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
