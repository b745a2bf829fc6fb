"""``Estimate``: the result every estimator returns: a model structure, its values and their quality.

An estimate is a :mod:`model structure <identify.structures>` (``structure``: ``linear``,
``bias``, ``friction``, ``dead-zone``, ...) with values for its parameters (``a``, ``b`` and
``extra``), the input delay (``input_delay``, samples), the covariance, the fit's diagnostics
and, from the default estimator, how it was selected.  The structure turns it into a model: a
python-control transfer function (:meth:`Estimate.transfer_function`: the linear part, with its
delay exact in discrete time), a python-control nonlinear system (:meth:`Estimate.io_system`:
everything, exact at the sample instants), a :class:`motorsim.plant.Motor`
(:meth:`Estimate.motor`).  Its JSON document (:meth:`Estimate.to_json`, :meth:`Estimate.from_json`;
``motorid identify --save`` and ``--json``) is :mod:`identify.model_file`'s.
"""
from __future__ import annotations

import dataclasses
import math
import os
import statistics
from typing import TYPE_CHECKING, Mapping, Sequence

import numpy as np

from motorsim.checks import ParameterError, check_int
from motorsim.plant import Plant

from .default.selection_report import SelectionReport
from .model_file import (
    ESTIMATE_FORMAT,
    MAX_ESTIMATE_BYTES,
    estimate_document,
    estimate_fields,
    file_sha256,
    json_ready,
    read_estimate_document,
)
from .model_structures import ModelStructure, structure, structure_fitted

if TYPE_CHECKING:
    import control

__all__ = ["Estimate", "json_ready", "file_sha256", "with_data_files", "ESTIMATE_FORMAT", "MAX_ESTIMATE_BYTES"]


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
    extra : mapping of str to float
        The structure's further parameters: ``friction`` (Coulomb friction ``c``) and ``bias``
        (constant acceleration ``d``) in rad/s^2, ``dead_zone`` in input units (an
        ``"input_delay"`` key given here is moved to :attr:`input_delay`).
    structure : str
        Name of the model structure (:func:`identify.structures`); every estimator names it.  When
        not given (an estimate made by hand), the registered structure whose parameters are exactly
        ``param_names`` (``a``, ``b``: the linear motor); refused when none is.
    input_delay : int
        Whole samples between a duty being commanded and reaching the motor, >= 0.
    residual_unit : str
        Unit of ``residual_rms``.
    input_unit : str
        Unit of the input ``u`` (``duty`` on the bench).
    data_files : tuple of (str, str)
        The recordings fitted, as ``(path, sha256 hex digest)`` (empty unless set, e.g. by
        ``motorid identify --save``).
    selection : SelectionReport, optional
        How the default estimator chose this model (:func:`identify.default.selection.fit_selected`):
        every candidate (structure, input delay, fit, score), the chosen one, the best, the
        runner-up, whether the choice was ``clear`` and the ``doubt`` line; None when a method
        was named.  A mapping given here (the JSON document's ``selection`` object) is read
        with :meth:`SelectionReport.from_dict`.
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
        :func:`identify.checks.uncertainty.robust_covariance`), ``"encoder-bootstrap"`` (``oe`` on a
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
    counts_per_rev : int, optional
        The encoder of the data the model was fitted to (counts per revolution; the recordings'
        ``counts_per_rev`` when they all share one), so a controller designed from the model knows
        the rig's sensor; None for a speed sensor or when unknown.
    speed_unit : str
        The speed unit of the data the model was fitted to (``rpm``, ...; the recording's
        ``speed_unit``), for showing results in it; every value here stays in rad/s.
    speed_residuals : tuple of ndarray, optional
        The fit's speed residual (measured minus model, rad/s) on each recording it was fitted on,
        in the order given, row by row exactly as :func:`identify.checks.validation.model_output` gives it
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
    selection: SelectionReport | None = None
    notes: tuple[str, ...] = ()
    model_range: Mapping[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    input_limit: float | None = None
    speed_unit: str = "rad/s"
    counts_per_rev: int | None = None
    speed_residuals: tuple[np.ndarray, ...] | None = dataclasses.field(default=None, repr=False)
    structure: str = ""
    input_delay: int = 0

    def __post_init__(self):
        extra = dict(self.extra)
        delay = extra.pop("input_delay", None)
        if delay is not None and self.input_delay == 0:
            object.__setattr__(self, "input_delay", delay)
        object.__setattr__(self, "input_delay", check_int("input_delay", self.input_delay, lo=0))
        object.__setattr__(self, "extra", {k: float(v) for k, v in extra.items()})
        found = structure(self.structure) if self.structure else structure_fitted(self.param_names)
        object.__setattr__(self, "structure", found.name)
        unset = [n for n in self.param_names if n not in ("a", "b", *self.extra)]
        if unset:
            raise ParameterError(f"param_names must each have a value (a, b or a key of extra), got {unset} "
                                 "without one")
        if self.covariance is not None:
            cov = np.array(self.covariance, dtype=float)
            if cov.shape != (len(self.param_names),) * 2:
                raise ParameterError(f"covariance must have shape {(len(self.param_names),) * 2}, got {cov.shape}")
            cov.setflags(write=False)
            object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "data_files", tuple((str(p), str(h)) for p, h in self.data_files))
        object.__setattr__(self, "notes", tuple(str(n) for n in self.notes))
        if isinstance(self.selection, Mapping):
            object.__setattr__(self, "selection", SelectionReport.from_dict(self.selection))
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
        units = {**self.model_structure().units(self.input_unit), "input_delay": "samples"}
        units = {k: v.replace("^2", "²") for k, v in units.items()}
        rows = []
        for name in ("a", "b", *self.extra, "input_delay"):
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

    def model_structure(self) -> ModelStructure:
        """The model structure this estimate gives values for (:func:`identify.structures`)."""
        return structure(self.structure)

    def values(self) -> dict[str, float]:
        """Every parameter of the structure by name (``a``, ``b`` and ``extra``; the delay is :attr:`input_delay`)."""
        return {"a": self.a, "b": self.b, **self.extra}

    @property
    def input_delay_seconds(self) -> float:
        """The input delay in s (``input_delay * sample_period``): what carries to another sample period."""
        return self.input_delay * self.sample_period

    def __repr__(self) -> str:
        extra = "".join(f", {k}={v:.6g}" for k, v in {**self.extra, "input_delay": self.input_delay}.items())
        return (f"Estimate(method={self.method!r}, a={self.a:.6g}, b={self.b:.6g}{extra}, "
                f"sample_period={self.sample_period:.6g}, fit_percent={self.fit_percent:.4g}, "
                f"n_samples={self.n_samples})")

    def __str__(self) -> str:
        """Value, standard error and 95 % interval of each parameter, then the fit (plain floats)."""
        se = self.stderr()
        ci = self.confidence_interval(0.95)
        delay_s = self.input_delay * self.sample_period
        units = {**self.model_structure().units(self.input_unit), "input_delay": f"samples ({delay_s:.6g} s)"}

        def line(name: str) -> str:
            text = f"{name:<11} {self.value(name):.6g} {units.get(name, '')}"
            if name in se and math.isfinite(se[name]):
                lo, hi = ci[name]
                text += f"   (stderr {se[name]:.2g})   95 % CI [{lo:.6g}, {hi:.6g}]"
            elif name in self.model_range:                # a level fitted by a profile: its bracket
                lo, hi = self.model_range[name]
                text += f"   range [{lo:.6g}, {hi:.6g}]"
            return text.rstrip()
        lines = [f"method      {self.method}", *(line(n) for n in ("a", "b", *self.extra, "input_delay")),
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
        """The estimate of parameter ``name`` (``a``, ``b``, a key of ``extra`` or ``input_delay``)."""
        if name in ("a", "b", "input_delay"):
            return getattr(self, name)
        if name in self.extra:
            return self.extra[name]
        raise KeyError(f"name must be one of {['a', 'b', *self.extra, 'input_delay']}, got {name!r}")

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
        return self.model_structure().transfer_function(self.values(), self.sample_period, self.input_delay,
                                                        form, delay=delay, pade_order=pade_order)

    def motor(self) -> Plant:
        """The identified model as the simulator's plant: its structure's (:class:`motorsim.plant.Motor` for the
        first-order family: friction, bias, dead zone, delay; :class:`motorsim.plant.Plant` in general)."""
        return self.model_structure().plant(self.values(), self.input_delay)

    def io_system(self, name: str = "motor") -> control.NonlinearIOSystem:
        """The full identified model as a discrete-time python-control system at :attr:`sample_period`.

        States ``angle`` (rad), ``speed`` (rad/s) and, with an input delay of ``d`` samples, the
        last ``d`` duties (``duty_1`` ... ``duty_d``, most recent first), then, behind an electrical
        lag, ``current`` (the lagged drive, in input units); input ``duty``; outputs ``speed`` and
        ``angle``.  Each step is the plant's exact step (:class:`motorsim.plant.Stepper`, as a closed
        loop on the simulated bench runs it): the zero-order-hold solution of the linear part,
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
        motor = self.motor().replace(input_delay=0)
        d, h = self.input_delay, self.sample_period
        stepper = motor.stepper(h)
        own = motor.state_names()[2:]            # the plant's own states (a lag's current), after the delay line
        n = len(own)

        def update(t, x, u, params):
            applied = x[2 + d - 1] if d else u[0]
            state = (x[0], x[1], *x[2 + d:2 + d + n]) if n else motor.initial_state(x[0], x[1])
            new = stepper.step(0, state, applied)
            return np.array([new[0], new[1], *([u[0], *x[2:2 + d - 1]] if d else []), *new[2:2 + n]])

        def output(t, x, u, params):
            return np.array([x[1], x[0]])
        states = ["angle", "speed", *(f"duty_{k}" for k in range(1, d + 1)), *own]
        return control.nlsys(update, output, inputs=["duty"], outputs=["speed", "angle"], states=states,
                             dt=h, name=name)

    def to_dict(self) -> dict:
        """The JSON-ready document of the estimate (``motorid identify --json``; the same as :meth:`to_json`'s).

        Its fields are :mod:`identify.model_file`'s: ``format``, ``structure``, ``method``, every
        parameter at the top level (``a``, ``b``, ``friction``, ...), ``input_delay`` (samples) and
        ``input_delay_seconds``, the covariance and per parameter ``NAME_stderr`` and
        ``NAME_ci95``, the units, notes, selection and the recordings fitted.
        """
        return estimate_document(self)

    def to_json(self, *, indent: int | None = 2) -> str:
        """Everything needed to rebuild the estimate, as a JSON document (:meth:`from_json` reads it).

        The document is :meth:`to_dict`'s (``format`` ``motorid estimate v2``): the same fields at
        the same paths as ``motorid identify --json`` prints.

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
        import json
        return json.dumps(self.to_dict(), indent=indent)

    @classmethod
    def from_json(cls, text: str | bytes) -> "Estimate":
        """The estimate :meth:`to_json` wrote (a JSON document, or the path of a file holding one).

        Documents of the first format (``motorid estimate v1``) are read too, and migrated.

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
        return cls(**estimate_fields(read_estimate_document(text)))


def with_data_files(estimate: Estimate, paths: Sequence[str | os.PathLike]) -> Estimate:
    """``estimate`` recording the paths and SHA-256 digests of the files it was fitted to."""
    return dataclasses.replace(estimate, data_files=tuple((os.fspath(p), file_sha256(p)) for p in paths))
