"""``motorid bench accuracy``: do the estimators reach the truth?

Recordings come from an integrator that is *not* the estimators' model: classical
Runge–Kutta 4 with fine sub-steps (``a delta <= 0.02`` per sub-step), the duty
held over each (possibly jittered) sample interval, integer duty, floored counts.
With Coulomb friction the sub-steps freeze the sign of the speed and clamp at a
zero crossing (sticking while ``|b u + d| <= c``).  ``motorsim.simulate`` is used
only to *report* how far the generator is from the exact ZOH solution.

Sections (each prints a table):

Each run has at least ``--samples`` samples and four periods of its lowest
frequency, and is lengthened until the Cramér–Rao bound of a and b is at most
0.025 % (the ``CRB`` column, relative), so that the 0.1 % criterion is a test of
the estimator (4 bounds of margin), not of an experiment too short to carry it.

1. sines over sample periods 1, 2, 5, 10, 20 ms, 1200/4096/16667 counts/rev,
   a = 4, 25, 90 1/s, sine frequency 0.3a, a, 2a (only below Nyquist):
   ``oe`` relative errors, next to the article's ``euler-ls`` and ``zoh-ls``;
2. multisines with +-10 % timing jitter, and with 1 % dropped samples;
3. Coulomb friction and a dead zone: ``oe-friction`` against ``oe``;
4. Monte Carlo with angle noise: ``oe``'s spread and bias against the Cramér–Rao bound;
5. the time of one ``oe`` fit of a 10 000-sample recording, analytic Jacobian
   against finite differences (``jac="2-point"``), measured in the same run; and
   ``oe-friction`` against ``oe`` on the same friction run, with and without a dead zone;
6. interval coverage: the share of 95 % intervals that cover the truth in each regime
   (white noise, coarse encoders, timing jitter, friction, a delay), ``--repetitions`` runs
   each, with the covariance used and std/CRB, for ``oe`` (``oe-friction`` with friction)
   and ``iv`` (every regime but friction);
7. closed loop: every method, and ``iv-reference`` (the reference as instrument), on a
   P position loop and a PI speed loop simulated here, and on the on-board controllers
   (one-step MPC, PI speed, PD position) run by ``SimRig`` with the firmware's fixed-point
   step; ``oe`` within 0.1 % of a and b on every run.

One benchmark in one module although it is long: the sections share the independent
integrator, the recording sizing and the table format, and run as one report.
"""
from __future__ import annotations

import argparse
import collections
import functools
import itertools
import math
import time
from typing import Callable, Sequence

import numpy as np

from motorid.bench.flags import integer, integers, real, reals
from motorid.bench.timing import median_time
from motorid.progress import Ticker
from motorsim.checks import ParameterTypeError
from motorsim.excitation import Multisine, Sine
from motorsim.recording import Recording
from motorsim.rig import jittered_times

__all__ = ["bench_accuracy", "rk4_angle", "rk4_friction_angle", "make_recording", "naive_output_error",
           "coverage_run", "COVERAGE_REGIMES", "closed_loop_run", "onboard_closed_loop_runs"]

_STATIC_GAIN = 0.12   # b / a in (rad/s)/duty, the article's 3/25
_SUBSTEP_AD = 0.02    # a * delta per RK4 sub-step: local error ~ (a delta)^5/120 ~ 3e-11


#: Goal for the time of oe-friction over oe on the same friction run.
_FRICTION_TIME_RATIO = 5.0


def rk4_angle(a: float, b: float, duty: np.ndarray, time_s: np.ndarray, *, initial_speed: float = 0.0) -> np.ndarray:
    """Angle in rad at ``time_s`` by RK4 sub-steps of ``[angle, speed, duty]' = A [angle, speed, duty]``.

    One RK4 step of a linear system is the matrix polynomial
    ``R = I + dA + (dA)^2/2 + (dA)^3/6 + (dA)^4/24``; ``m`` sub-steps per interval
    give ``R^m`` (an approximation of ``expm(A h)`` of order 4, not the closed form).
    """
    h = np.diff(time_s)
    m = max(4, int(math.ceil(a * float(h.max()) / _SUBSTEP_AD)))
    A = np.array([[0.0, 1.0, 0.0], [0.0, -a, b], [0.0, 0.0, 0.0]])
    d = (h / m)[:, None, None]
    Ad = d * A
    R = np.eye(3) + Ad + Ad @ Ad / 2 + Ad @ Ad @ Ad / 6 + Ad @ Ad @ Ad @ Ad / 24
    phi = np.linalg.matrix_power(R, m)          # (n-1, 3, 3)
    n = len(time_s)
    angle = np.zeros(n)
    th, w = 0.0, float(initial_speed)
    p00, p01, p02 = phi[:, 0, 0], phi[:, 0, 1], phi[:, 0, 2]
    p11, p12 = phi[:, 1, 1], phi[:, 1, 2]
    for k in range(n - 1):
        u = duty[k]
        th, w = p00[k] * th + p01[k] * w + p02[k] * u, p11[k] * w + p12[k] * u
        angle[k + 1] = th
    return angle


def rk4_friction_angle(a: float, b: float, c: float, d: float, duty: np.ndarray, time_s: np.ndarray, *,
                       dead_zone: float = 0.0, substeps: int = 64) -> np.ndarray:
    """Angle of ``w' = -a w + b v - c sign(w) + d`` (v: duty through the dead zone) by sub-stepped RK4.

    ``duty`` may be 2-D ``(n, cases)`` to integrate several runs at once.  At rest the
    motor sticks while ``|b v + d| <= c``; in a sub-step that crosses zero speed the
    crossing is located by linear interpolation and the rest of the sub-step restarts
    from rest (stuck, or on the other branch).
    """
    u = np.asarray(duty, float)
    if u.ndim == 1:
        u = u[:, None]
    v = np.where(np.abs(u) <= dead_zone, 0.0, u - np.sign(u) * dead_zone)
    n, cases = u.shape
    th = np.zeros(cases)
    w = np.zeros(cases)
    out = np.zeros((n, cases))
    for k in range(n - 1):
        dt = (time_s[k + 1] - time_s[k]) / substeps
        force = b * v[k] + d
        for _ in range(substeps):
            moving = w != 0
            s = np.where(moving, np.sign(w), np.sign(force))
            stuck = ~moving & (np.abs(force) <= c)
            w_new, dth = _rk4_branch(a, force - c * s, w, dt)
            crossed = moving & (np.sign(w_new) != s)
            if np.any(crossed):
                # the speed reaches zero inside the sub-step: locate it (linear interpolation),
                # then restart from rest for the remainder, stuck or on the other branch
                frac = np.where(crossed, w / np.where(crossed, w - w_new, 1.0), 1.0)
                rest = (1.0 - frac) * dt
                s2 = np.sign(force)
                free = np.abs(force) > c
                w_rest, th_rest = _rk4_branch(a, force - c * s2, np.zeros_like(w), rest)
                w_new = np.where(crossed, np.where(free, w_rest, 0.0), w_new)
                dth = np.where(crossed, frac * dt * w / 2 + np.where(free, th_rest, 0.0), dth)
            w = np.where(stuck, 0.0, w_new)
            th = th + np.where(stuck, 0.0, dth)
        out[k + 1] = th
    return out if np.ndim(duty) == 2 else out[:, 0]


def _rk4_branch(a, f, w, dt):
    """One RK4 step of ``[angle, speed]' = [speed, -a speed + f]``: (new speed, angle increment)."""
    k1 = -a * w + f
    w2 = w + dt / 2 * k1
    k2 = -a * w2 + f
    w3 = w + dt / 2 * k2
    k3 = -a * w3 + f
    w4 = w + dt * k3
    k4 = -a * w4 + f
    return w + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), dt / 6 * (w + 2 * w2 + 2 * w3 + w4)


def make_recording(angle: np.ndarray, duty: np.ndarray, time_s: np.ndarray, sample_period: float,
                   counts_per_rev: int, *, rng: np.random.Generator | None = None, drop_rate: float = 0.0,
                   angle_noise: float = 0.0) -> Recording:
    """Floored counts (optional noise and dropped rows) as a Recording; ``rng`` is needed for either."""
    if (angle_noise or drop_rate) and not isinstance(rng, np.random.Generator):
        raise ParameterTypeError("rng must be a numpy.random.Generator when angle_noise or drop_rate is set, "
                                 f"got {type(rng).__name__}")
    noisy = angle + (rng.normal(0.0, angle_noise, len(angle)) if rng is not None and angle_noise else 0.0)
    counts = np.floor(noisy * counts_per_rev / (2 * math.pi)).astype(np.int64) + 1000
    keep = np.ones(len(angle), bool)
    if rng is not None and drop_rate:
        keep[1:] = rng.random(len(angle) - 1) >= drop_rate
    return Recording(time=time_s[keep], duty=duty[keep], sample_period=sample_period, counts=counts[keep],
                     seq=np.flatnonzero(keep), counts_per_rev=counts_per_rev)


def _n_samples(dt: float, lowest_freq: float, minimum: int) -> int:
    return max(minimum, int(math.ceil(4 * 2 * math.pi / lowest_freq / dt)))


def _sized(a: float, b: float, make_duty, dt: float, cpr: int, n0: int, target: float, cap: int) -> tuple[int, float]:
    """Samples needed for the Cramér–Rao bound of a and b to fall to ``target`` (relative), and that bound.

    The bound falls as ``1/sqrt(n)``; experiments whose information is too thin at
    ``n0`` are lengthened (up to ``cap``) so that the 0.1 % criterion tests the
    estimator, not the experiment.
    """
    from identify import cramer_rao_bound
    rel = cramer_rao_bound(a, b, make_duty(n0), dt, counts_per_rev=cpr).relative_stderr()
    worst = max(rel.values())
    n = n0 if worst <= target else min(cap, int(math.ceil(n0 * (worst / target) ** 2)))
    return n, worst * math.sqrt(n0 / n)


def _rel(est, a, b) -> tuple[float, float]:
    return est.a / a - 1.0, est.b / b - 1.0


def _fit_or_nan(method, rec, a, b, **kw):
    from identify import NotIdentifiableError, fit, method_options
    if "input_delay" in method_options(method):
        kw.setdefault("input_delay", 0)                   # these runs have none: the fit at the known delay
    try:
        return _rel(fit(rec, method=method, outliers="keep", **kw), a, b)
    except NotIdentifiableError:
        return math.nan, math.nan


def _friction_of(est) -> float:
    """The fitted Coulomb friction of an oe-friction estimate (rad/s^2)."""
    return est.extra.get("friction", math.nan)


def _pct(x: float) -> str:
    return f"{100 * x:+9.4f}" if math.isfinite(x) else "      n/a"


def _sine_case(args, dt: float, cpr: int, a: float, ratio: float, rng) -> tuple[float, ...] | None:
    """Relative errors of oe (a, b), euler-ls (a), zoh-ls (a), iv (a, b) on one sine, with n and the CRB."""
    b = _STATIC_GAIN * a
    f = ratio * a
    if f * dt >= 0.9 * math.pi:
        return None
    exc = Sine(f, 200, 0.3)
    n, crb = _sized(a, b, lambda m: exc.duty(m, dt).astype(float), dt, cpr,
                    _n_samples(dt, f, args.samples), args.crb_target, args.max_samples)
    t = jittered_times(n, dt, 0.0, rng)
    duty = exc.duty(n, dt).astype(float)
    rec = make_recording(rk4_angle(a, b, duty, t), duty, t, dt, cpr)
    ea, eb = _fit_or_nan("oe", rec, a, b)
    ua, _ = _fit_or_nan("euler-ls", rec, a, b)
    za, _ = _fit_or_nan("zoh-ls", rec, a, b)
    ia, ib = _fit_or_nan("iv", rec, a, b)
    return n, crb, ea, eb, ua, za, ia, ib


def _section_sines(args, rng) -> tuple[bool, list]:
    print("\n1. sines, oe vs the article's euler-ls and zoh-ls (relative error in %; n = samples)")
    print(f"{'dt ms':>5} {'cpr':>6} {'a':>4} {'f/a':>4} {'n':>6} {'CRB':>7}  {'oe a':>9} {'oe b':>9}  "
          f"{'euler a':>9} {'zoh-ls a':>9} {'iv a':>9} {'iv b':>9}")
    worst, worst_euler, worst_zoh, worst_iv, rows = 0.0, [], [], [], []
    ok = True
    for dt, cpr, a, ratio in itertools.product(args.sample_periods, args.counts, args.poles, args.ratios):
        case = _sine_case(args, dt, cpr, a, ratio, rng)
        if case is None:
            rows.append((dt, cpr, a, ratio, "above 0.9 Nyquist"))
            print(f"{dt * 1e3:5g} {cpr:6d} {a:4g} {ratio:4g}      -  (sine above 0.9 x Nyquist, skipped)")
            continue
        n, crb, ea, eb, ua, za, ia, ib = case
        worst_zoh.append(abs(za) if math.isfinite(za) else math.inf)
        worst_iv.append(max(abs(ia), abs(ib)) if math.isfinite(ia) else math.inf)
        bad = not (abs(ea) <= 1e-3 and abs(eb) <= 1e-3)
        ok &= not bad
        worst = max(worst, abs(ea), abs(eb))
        if math.isfinite(ua):
            worst_euler.append(abs(ua))
        print(f"{dt * 1e3:5g} {cpr:6d} {a:4g} {ratio:4g} {int(n):6d} {100 * crb:7.4f}  {_pct(ea)} {_pct(eb)}  "
              f"{_pct(ua)} {_pct(za)} {_pct(ia)} {_pct(ib)}" + ("   <-- above 0.1 %" if bad else ""))
    print(f"worst |oe error| {100 * worst:.4f} %  (criterion 0.1 %)   "
          f"euler-ls |a error| from {100 * min(worst_euler):.2f} % to {100 * max(worst_euler):.2f} %")
    finite_iv = [x for x in worst_iv if math.isfinite(x)]
    print(f"zoh-ls |a error| median {100 * float(np.median(worst_zoh)):.2f} %, failed {worst_zoh.count(math.inf)}; "
          f"iv |error| median {100 * float(np.median(finite_iv)):.4f} %, worst {100 * max(finite_iv):.3f} %, "
          f"failed {len(worst_iv) - len(finite_iv)} of {len(worst_iv)}")
    return ok, rows


def _multisine_case(args, dt: float, cpr: int, a: float, jitter: float, drop: float, rng):
    """(samples kept, CRB, oe a, oe b, euler-ls a) relative errors on one multisine, or None above Nyquist."""
    b = _STATIC_GAIN * a
    freqs = [r * a for r in (0.3, 1.0, 2.0) if r * a * dt < 0.9 * math.pi]
    if not freqs:
        return None
    exc = Multisine(tuple(freqs), (200 // len(freqs) + 20,) * len(freqs), tuple(0.7 * i for i in range(len(freqs))))
    n, crb = _sized(a, b, lambda m: exc.duty(m, dt).astype(float), dt, cpr,
                    _n_samples(dt, freqs[0], args.samples), args.crb_target, args.max_samples)
    t = jittered_times(n, dt, jitter, rng)
    duty = exc.duty(n, dt).astype(float)
    rec = make_recording(rk4_angle(a, b, duty, t), duty, t, dt, cpr, rng=rng, drop_rate=drop)
    ea, eb = _fit_or_nan("oe", rec, a, b)
    ua, _ = _fit_or_nan("euler-ls", rec, a, b)
    return len(rec), crb, ea, eb, ua


def _section_multisine(args, rng) -> bool:
    print("\n2. multisines (0.3a, a, 2a below Nyquist), 16667/1200 counts: jitter +-10 % and 1 % dropped samples")
    print(f"{'case':>8} {'dt ms':>5} {'cpr':>6} {'a':>4} {'n':>6} {'CRB':>7}  {'oe a':>9} {'oe b':>9}  {'euler a':>9}")
    ok = True
    worst = {"jitter": 0.0, "drops": 0.0}
    for case, jitter, drop, limit in (("jitter", 0.1, 0.0, 1e-3), ("drops", 0.0, 0.01, 5e-3)):
        for dt, cpr, a in itertools.product(args.sample_periods, (1200, 16667), args.poles):
            result = _multisine_case(args, dt, cpr, a, jitter, drop, rng)
            if result is None:
                continue
            n, crb, ea, eb, ua = result
            bad = not (abs(ea) <= limit and abs(eb) <= limit)
            ok &= not bad
            worst[case] = max(worst[case], abs(ea), abs(eb))
            print(f"{case:>8} {dt * 1e3:5g} {cpr:6d} {a:4g} {n:6d} {100 * crb:7.4f}  "
                  f"{_pct(ea)} {_pct(eb)}  {_pct(ua)}" + (f"   <-- above {100 * limit:g} %" if bad else ""))
    print(f"worst |oe error|: jitter {100 * worst['jitter']:.4f} % (criterion 0.1 %), "
          f"1 % drops {100 * worst['drops']:.4f} % (criterion 0.5 %)")
    return ok


def _section_friction(args, rng) -> bool:
    from identify import available_methods, fit
    if "oe-friction" not in available_methods():
        print("\n3. friction: oe-friction not available in this build")
        return True
    print("\n3. Coulomb friction c (and a dead zone), 5 ms, 4096 counts: oe-friction vs oe (relative error in %)")
    print(f"{'a':>4} {'c':>6} {'dz':>4} {'input':>10}  {'oe-fr a':>9} {'oe-fr b':>9}  {'oe a':>9} {'oe b':>9}"
          f"  {'c est':>8}")
    dt, cpr, n = 0.005, 4096, args.friction_samples
    t = np.arange(n) * dt
    cases = []
    for a in (10.0, 25.0):
        b = _STATIC_GAIN * a
        for c_rel, dz in ((0.25, 0.0), (0.25, 10.0)):
            for label, duty in (("sine a", Sine(a, 200, 0.3).duty(n, dt)),
                                ("sine 0.3a", Sine(0.3 * a, 200, 0.3).duty(n, dt))):
                cases.append((a, b, c_rel * b * 100, dz, label, duty.astype(float)))
    ok = True
    worst_fr, worst_oe = 0.0, 0.0
    # integrate the cases with the same a together (vectorised over cases)
    for a in sorted({c[0] for c in cases}):
        group = [c for c in cases if c[0] == a]
        for c_val, dz in sorted({(c[2], c[3]) for c in group}):
            sub = [g for g in group if (g[2], g[3]) == (c_val, dz)]
            angles = rk4_friction_angle(a, sub[0][1], c_val, 0.0, np.column_stack([g[5] for g in sub]), t,
                                        dead_zone=dz)
            for j, (a_, b_, c_, dz_, label, duty) in enumerate(sub):
                rec = make_recording(angles[:, j], duty, t, dt, cpr)
                fr = fit(rec, method="oe-friction", outliers="keep", input_delay=0)
                fa, fb = _rel(fr, a_, b_)
                oa, ob = _fit_or_nan("oe", rec, a_, b_)
                bad = not (abs(fa) <= 0.02 and abs(fb) <= 0.02)
                ok &= not bad
                worst_fr = max(worst_fr, abs(fa), abs(fb))
                worst_oe = max(worst_oe, abs(oa), abs(ob)) if math.isfinite(oa) else worst_oe
                print(f"{a_:4g} {c_:6.2f} {dz_:4g} {label:>10}  {_pct(fa)} {_pct(fb)}  {_pct(oa)} {_pct(ob)}"
                      f"  {_friction_of(fr):8.3f}" + ("   <-- above 2 %" if bad else ""))
    print(f"worst |error|: oe-friction {100 * worst_fr:.3f} % (criterion 2 %), oe {100 * worst_oe:.2f} %")
    return ok


def _section_monte_carlo(args) -> bool:
    from identify import NotIdentifiableError, cramer_rao_bound, fit
    a, b, dt, cpr, noise = 25.0, 3.0, 0.005, 16667, args.angle_noise
    n = args.samples
    duty = Multisine((0.3 * a, a, 2 * a), (90, 90, 90), (0.0, 0.7, 1.4)).duty(n, dt).astype(float)
    t = np.arange(n) * dt
    angle = rk4_angle(a, b, duty, t)
    crb = cramer_rao_bound(a, b, duty, dt, counts_per_rev=cpr, angle_noise=noise).stderr()
    rows = []
    for child in np.random.SeedSequence(args.seed).spawn(args.repetitions):
        rng = np.random.default_rng(child)
        try:
            fitted = fit(make_recording(angle, duty, t, dt, cpr, rng=rng, angle_noise=noise), method="oe",
                         outliers="keep", input_delay=0)
            rows.append((fitted.a, fitted.b, fitted.stderr()["a"], fitted.stderr()["b"]))
        except NotIdentifiableError:
            pass
    e = np.array(rows)
    sd = e[:, :2].std(axis=0, ddof=1)
    bias = e[:, :2].mean(axis=0) - (a, b)
    rep = e[:, 2:].mean(axis=0)
    print(f"\n4. Monte Carlo: {len(e)} runs, a={a:g}, b={b:g}, dt={dt * 1e3:g} ms, {cpr} counts/rev, "
          f"angle noise {noise:g} rad, n={n}, multisine")
    print(f"{'':>4} {'std':>11} {'CRB':>11} {'std/CRB':>8} {'bias':>11} {'bias/std':>8} {'mean stderr':>11}")
    ok = True
    for i, name in enumerate(("a", "b")):
        ratio = sd[i] / crb[name]
        br = abs(bias[i]) / sd[i]
        ok &= ratio <= 1.3 and br < 1.0
        print(f"{name:>4} {sd[i]:11.4g} {crb[name]:11.4g} {ratio:8.3f} {bias[i]:+11.3g} {br:8.3f} {rep[i]:11.4g}")
    print("criteria: std within 1.3 x CRB, |bias| below one std")
    return ok


#: Regimes of the coverage table: (label, method, counts/rev, angle noise rad, jitter share of dt, friction c, delay).
_OE_REGIMES = (
    ("white angle noise", "oe", 16667, 2e-3, 0.0, 0.0, 0),
    ("44 counts/rev", "oe", 44, 0.0, 0.0, 0.0, 0),
    ("100 counts/rev", "oe", 100, 0.0, 0.0, 0.0, 0),
    ("360 counts/rev", "oe", 360, 0.0, 0.0, 0.0, 0),
    ("timing jitter 10 %", "oe", 4096, 0.0, 0.1, 0.0, 0),
    ("Coulomb friction", "oe-friction", 4096, 0.0, 0.0, 75.0, 0),
    ("input delay 2", "oe", 4096, 0.0, 0.0, 0.0, 2),
)
#: ... and ``iv``, which reports intervals too, in the same regimes but friction (no linear model fits it).
COVERAGE_REGIMES = _OE_REGIMES + tuple((label, "iv", *rest) for label, method, *rest in _OE_REGIMES
                                       if method == "oe")
_COVERAGE_GOAL = 0.90
_NOISE_FREE_ANGLES: dict = {}   # the last regime's noise-free angle (without jitter every run shares it)


def coverage_run(regime, duty: np.ndarray, dt: float, rng) -> tuple[bool, bool, str, float, float] | None:
    """One run of a regime: whether the 95 % intervals of a and b cover the truth, the covariance used,
    and the estimates of a and b.

    Randomness: the encoder's phase (a uniform offset within one count), the angle noise and the
    sample instants' jitter (the recording keeps the nominal clock, as the firmware does)."""
    from identify import NotIdentifiableError, fit, method_options
    label, method, cpr, noise, jitter, friction, delay = regime
    a, b, n = 25.0, 3.0, len(duty)
    nominal = np.arange(n) * dt
    true_t = nominal + (rng.uniform(-jitter, jitter, n) * dt if jitter else 0.0)
    true_t[0] = 0.0
    key = (friction, delay, dt, duty.tobytes())
    if jitter or key not in _NOISE_FREE_ANGLES:
        delayed = np.concatenate([np.zeros(delay), duty[:n - delay]]) if delay else duty
        if friction:
            angle = rk4_friction_angle(a, b, friction, 0.0, delayed[:, None], true_t)[:, 0]
        else:
            angle = rk4_angle(a, b, delayed, true_t)
        if not jitter:      # the same for every run: integrate once
            _NOISE_FREE_ANGLES.clear()
            _NOISE_FREE_ANGLES[key] = angle
    else:
        angle = _NOISE_FREE_ANGLES[key]
    angle = angle + rng.uniform(0.0, 2 * math.pi / cpr)
    rec = make_recording(angle, duty, nominal, dt, cpr, rng=rng, angle_noise=noise)
    options: dict = {"input_delay": delay} if delay or "input_delay" in method_options(method) else {}
    if method == "oe-friction":
        options["dead_zone"] = False
    try:
        est = fit(rec, method=method, outliers="keep", **options)
    except NotIdentifiableError:
        return None
    lo_hi = est.confidence_interval(0.95)
    return (lo_hi["a"][0] <= a <= lo_hi["a"][1], lo_hi["b"][0] <= b <= lo_hi["b"][1], est.covariance_method,
            est.a, est.b)


def _section_coverage(args) -> bool:
    """Share of runs whose 95 % intervals of a and b cover the truth, per regime."""
    dt, n = 0.005, args.coverage_samples
    duty = Multisine((7.5, 25.0, 50.0), (90, 90, 90), (0.0, 0.7, 1.4)).duty(n, dt).astype(float)
    print(f"\n6. interval coverage: {args.repetitions} runs per regime, a=25, b=3, {n} samples of 5 ms, "
          f"multisine; share of 95 % intervals that cover the truth (goal >= {100 * _COVERAGE_GOAL:g} %)")
    print(f"{'regime':>20} {'method':>12} {'runs':>5} {'a covered':>10} {'b covered':>10} {'covariance':>33} "
          f"{'std/CRB a':>9} {'std/CRB b':>9}")
    ok = True
    for i, regime in enumerate(COVERAGE_REGIMES):
        rows = []
        for child in np.random.SeedSequence([args.seed, i]).spawn(args.repetitions):
            out = coverage_run(regime, duty, dt, np.random.default_rng(child))
            if out is not None:
                rows.append(out)
        ca = float(np.mean([r[0] for r in rows])) if rows else math.nan
        cb = float(np.mean([r[1] for r in rows])) if rows else math.nan
        used = collections.Counter(r[2] for r in rows).most_common(1)
        how = f"{used[0][0]} {100 * used[0][1] / len(rows):.0f}%" if used else "-"
        ratio = _std_over_crb(regime, duty, dt, np.array([r[3:] for r in rows]))
        bad = not (ca >= _COVERAGE_GOAL and cb >= _COVERAGE_GOAL)
        ok &= not bad
        print(f"{regime[0]:>20} {regime[1]:>12} {len(rows):5d} {100 * ca:9.1f}% {100 * cb:9.1f}% {how:>33} "
              f"{ratio[0]:9.2f} {ratio[1]:9.2f}" + ("   <-- below goal" if bad else ""))
    print("std/CRB: spread of the estimates over the Cramér–Rao bound of the regime's model (quantisation "
          "as white noise; nan with jitter, which the bound does not model).  euler-ls and zoh-ls are not "
          "here: their intervals are the speed regression's and leave out its bias (section 1), so they "
          "are not intervals for the motor's a and b")
    return ok


def closed_loop_run(loop: str, a: float, b: float, dt: float, n: int, cpr: int, rng) -> Recording:
    """A closed-loop recording: the duty computed each sample from the floored counts.

    ``loop = "position"``: ``u = 60 (r - theta_meas)`` duty/rad tracking ``r = 3 sin(2 t)`` rad.
    ``loop = "speed"``: PI on the differenced counts, ``u = 8 e + 40 integral(e)`` tracking
    ``r = 10 sin(3 t) + 4`` rad/s.  Duty rounded and saturated at +-255; the plant stepped
    exactly (ZOH) between samples; the encoder's phase random (``rng``).  The recording
    carries the reference column (rad or rad/s).
    """
    e = math.exp(-a * dt)
    p = (1 - e) / a
    q = (dt - p) / a
    step = 2 * math.pi / cpr
    phase = rng.uniform(0.0, step)
    w = th = 0.0
    integral = 0.0
    previous = 0.0
    counts = np.empty(n, np.int64)
    duty = np.empty(n)
    t = np.arange(n) * dt
    reference = 3.0 * np.sin(2.0 * t) if loop == "position" else 10.0 * np.sin(3.0 * t) + 4.0
    for k in range(n):
        counts[k] = math.floor((th + phase) / step)
        measured = counts[k] * step
        if loop == "position":
            u = 60.0 * (reference[k] - measured)
        else:
            speed = (measured - previous) / dt if k else 0.0
            err = reference[k] - speed
            integral += err * dt
            u = 8.0 * err + 40.0 * integral
        previous = measured
        duty[k] = u = float(min(255.0, max(-255.0, round(u))))
        th, w = th + p * w + q * b * u, e * w + p * b * u
    return Recording(time=t, duty=duty, sample_period=dt, counts=counts, counts_per_rev=cpr,
                     reference=reference)


def onboard_closed_loop_runs(a: float, b: float, dt: float, duration: float, cpr: int, runs: int,
                             seed: int) -> list[tuple[str, list[Recording]]]:
    """Closed-loop recordings of the on-board controllers, run by ``SimRig`` as a device runs them.

    Each controller of :mod:`motorsim.control` is designed from the true ``a, b`` and run with
    its fixed-point step (the firmware's arithmetic) on floored counts of a ``cpr`` encoder,
    no noise: the one-step MPC tracking ``10 sin(3 t + phi) + 4`` rad/s, the PI speed loop the
    same reference, the PD position loop ``3 sin(2 t + phi)`` rad.  ``phi`` is drawn per run
    (``numpy.random.default_rng([seed, run])``), so the runs quantise differently.

    Returns
    -------
    list of (str, list of Recording)
        A label and ``runs`` recordings per controller.
    """
    from motorsim import Encoder, Motor, SimRig
    from motorsim.control import ClosedLoopExperiment, OneStepMPC, PISpeed, PlantModel, PositionPD, Reference
    model = PlantModel(a, b, dt, cpr)
    rig = SimRig(Motor(a, b), Encoder(counts_per_rev=cpr))
    loops = (("one-step MPC, SimRig", OneStepMPC(model), 3.0, 10.0, 4.0),
             ("PI speed, SimRig", PISpeed(model), 3.0, 10.0, 4.0),
             ("PD position, SimRig", PositionPD(model), 2.0, 3.0, 0.0))
    out = []
    for label, controller, freq, amp, offset in loops:
        phases = [float(np.random.default_rng([seed, r]).uniform(0.0, 2 * math.pi)) for r in range(runs)]
        refs = [Reference("sine", offset, (freq,), (amp,), (phi,)) for phi in phases]
        out.append((label, [rig.run(ClosedLoopExperiment(controller, ref, duration)) for ref in refs]))
    return out


#: oe's goal on closed-loop recordings: every run within this relative error of a and b.
_CLOSED_LOOP_GOAL = 1e-3
#: A method whose mean error passes this on a loop is flagged as biased there.
_BIASED = 1e-2


def _closed_loop_errors(method: str, rec: Recording, a: float, b: float) -> tuple[float, float]:
    """Relative errors of a and b of one method (``iv-reference`` included) on one recording."""
    return _fit_or_nan(method, rec, a, b)


def _section_closed_loop(args) -> bool:
    """Every method on closed-loop recordings (duty computed from the measured counts); oe within 0.1 %?"""
    from identify import available_methods
    a, b, dt, n, cpr = 25.0, 3.0, 0.005, 4000, 1200
    runs, onboard_runs = 5, 3
    print(f"\n7. closed loop: a={a:g}, b={b:g}, {n} samples of {dt * 1e3:g} ms, {cpr} counts/rev, floored, no "
          f"noise; mean and spread of the relative error (%) over {runs} runs (encoder phase random) or "
          f"{onboard_runs} runs (SimRig: reference phase random)")
    print(f"{'loop':>24} {'method':>12} {'a error %':>18} {'b error %':>18}")
    loops = [(label, [closed_loop_run(loop, a, b, dt, n, cpr, np.random.default_rng([args.seed, r]))
                      for r in range(runs)])
             for loop, label in (("position", "P position, floored"), ("speed", "PI speed, differenced"))]
    loops += onboard_closed_loop_runs(a, b, dt, n * dt, cpr, onboard_runs, args.seed)
    ok = True
    methods = available_methods(first_order=True)
    for label, recs in loops:
        errs = {m: np.array([_closed_loop_errors(m, rec, a, b) for rec in recs]) * 100 for m in methods}
        mean = {m: np.nanmean(e, axis=0) for m, e in errs.items()}
        alternative = "oe" + (", or iv-reference" if np.all(np.abs(mean["iv-reference"]) <= 100 * _BIASED) else "")
        for m in methods:
            spread = np.nanstd(errs[m], axis=0)
            note = ""
            if m == "oe" and not np.all(np.abs(errs[m]) < 100 * _CLOSED_LOOP_GOAL):
                ok, note = False, f"   <-- beyond the {100 * _CLOSED_LOOP_GOAL:g} % goal"
            elif np.any(np.abs(mean[m]) > 100 * _BIASED):
                note = f"   biased: use {alternative}"
            print(f"{label:>24} {m:>12} {mean[m][0]:+9.3f} +-{spread[0]:7.3f} {mean[m][1]:+9.3f} +-{spread[1]:7.3f}"
                  f"{note}")
    print(f"goal: oe within {100 * _CLOSED_LOOP_GOAL:g} % of a and b on every run.  biased: a mean error beyond "
          f"{100 * _BIASED:g} %.  iv-reference: instrumental variables with the recorded reference as instrument "
          f"(identify.fit_reference_iv), consistent when the measurement error is independent of the reference; "
          f"a coarse encoder's error is not (it follows the trajectory the reference drives)")
    return ok


def _std_over_crb(regime, duty: np.ndarray, dt: float, estimates: np.ndarray) -> tuple[float, float]:
    """Standard deviation of the estimates of a and b over their Cramér–Rao bound (nan with jitter)."""
    from identify import cramer_rao_bound
    _, _, cpr, noise, jitter, friction, delay = regime
    if jitter or len(estimates) < 2:
        return math.nan, math.nan
    crb = cramer_rao_bound(25.0, 3.0, duty, dt, counts_per_rev=cpr, angle_noise=noise, friction=friction,
                           input_delay=delay).stderr()
    sd = estimates.std(axis=0, ddof=1)
    return float(sd[0] / crb["a"]), float(sd[1] / crb["b"])


def naive_output_error(recording: Recording) -> tuple[float, float]:
    """The same output-error fit done plainly: all of ``(a, b, omega0, theta0)`` by Levenberg–Marquardt
    with a finite-difference Jacobian, no projection (one gap-free recording).  The timing baseline."""
    from scipy.optimize import least_squares

    from identify import fit_zoh_ls
    from identify.fits.sensitivity import zoh_response
    y = np.asarray(recording.measured_angle())
    t, u = recording.time, recording.duty
    start = fit_zoh_ls(recording)

    def residuals(x):
        return y - x[3] - zoh_response(x[0], x[1], u, t, x[2], sensitivities=False).angle
    w0 = (y[3] - y[0]) / (t[3] - t[0])
    res = least_squares(residuals, [start.a, start.b, w0, y[0]], jac="2-point", method="lm", x_scale="jac",
                        xtol=1e-11, ftol=1e-11, gtol=1e-11)
    return float(res.x[0]), float(res.x[1])


def _time_fits(rec: Recording, repeats: int) -> str:
    """One line: oe's fit time against its finite-difference and plain baselines, zoh-ls and iv."""
    from identify import fit_zoh_ls
    from identify.fits.instrumental import fit_instrumental_variables
    from identify.fits.output_error import fit_output_error
    t_an = median_time(lambda: fit_output_error(rec, input_delay=0), repeats)
    t_fd = median_time(lambda: fit_output_error(rec, jac="2-point", input_delay=0), repeats)
    t_ls = median_time(lambda: fit_zoh_ls(rec), repeats)
    t_iv = median_time(lambda: fit_instrumental_variables(rec, input_delay=0), repeats)
    if rec.has_gaps:
        plain = "(b) n/a: one gap-free run only"
    else:
        ours = fit_output_error(rec, input_delay=0)
        naive = naive_output_error(rec)
        agree = max(abs(naive[0] / ours.a - 1), abs(naive[1] / ours.b - 1))
        t_nv = median_time(lambda: naive_output_error(rec), repeats)
        plain = f"(b) {t_nv * 1e3:6.1f} ms, ratio {t_nv / t_an:4.2f} x, same a, b to {agree:.0e}"
    return (f"oe {t_an * 1e3:6.1f} ms | (a) {t_fd * 1e3:6.1f} ms, ratio {t_fd / t_an:4.2f} x | "
            f"{plain} | zoh-ls {t_ls * 1e3:.1f} ms, iv {t_iv * 1e3:.1f} ms")


def _section_timing(args) -> None:
    a, b, dt, n = 25.0, 3.0, 0.005, 10_000
    rng = np.random.default_rng(args.seed)
    duty = Sine(10.0, 200).duty(n, dt).astype(float)
    print(f"\n5. time of one fit, {n} samples (median of {args.repeats}); baselines: the same fit with a "
          "finite-difference Jacobian (a) on the projected problem, (b) on all of a, b, omega0, theta0")
    for label, jitter, drop in (("uniform clock", 0.0, 0.0), ("10 % jitter", 0.1, 0.0),
                                ("1 % drops", 0.1, 0.01)):
        t = jittered_times(n, dt, jitter, rng)
        rec = make_recording(rk4_angle(a, b, duty, t), duty, t, dt, 16667, rng=rng, drop_rate=drop)
        print(f"{label:>14}: {_time_fits(rec, args.repeats)}")
    _time_friction(args)


def _time_friction(args) -> None:
    """oe-friction against oe on the same friction run (one 10 000-sample run each, with and without a dead zone)."""
    from identify import available_methods, fit
    if "oe-friction" not in available_methods():
        return
    a, b, dt, n, cpr = 25.0, 3.0, 0.005, 10_000, 4096
    c = 0.25 * b * 100
    t = np.arange(n) * dt
    duty = Sine(10.0, 200, 0.3).duty(n, dt).astype(float)
    print(f"oe-friction vs oe on the same run: {n} samples, a={a:g}, b={b:g}, c={c:g}, {cpr} counts, sine 10 rad/s "
          f"(median of {args.repeats}, the two fits in turn; goal ratio <= {_FRICTION_TIME_RATIO:g})")
    for zone in (0.0, 10.0):
        rec = make_recording(rk4_friction_angle(a, b, c, 0.0, duty[:, None], t, dead_zone=zone)[:, 0],
                             duty, t, dt, cpr)
        t_oe, t_fr = _interleaved_medians([functools.partial(fit, rec, method="oe", input_delay=0),
                                           functools.partial(fit, rec, method="oe-friction", dead_zone=zone > 0,
                                                             input_delay=0)],
                                          args.repeats)
        fr = fit(rec, method="oe-friction", outliers="keep", dead_zone=zone > 0, input_delay=0)
        fa, fb = _rel(fr, a, b)
        print(f"  dead zone {zone:4g}: oe {t_oe * 1e3:6.1f} ms, oe-friction {t_fr * 1e3:6.1f} ms, "
              f"ratio {t_fr / t_oe:5.2f} x; oe-friction error a {_pct(fa)} b {_pct(fb)} %, "
              f"c {_friction_of(fr):.3f} (true {c:g})")


def _interleaved_medians(funcs: Sequence[Callable[[], object]], repeats: int) -> list[float]:
    """Median wall-clock seconds of each function, the calls taken in turn so that all see the same load."""
    times: list[list[float]] = [[] for _ in funcs]
    for f in funcs:
        f()
    for _ in range(repeats):
        for f, spent in zip(funcs, times):
            t0 = time.perf_counter()
            f()
            spent.append(time.perf_counter() - t0)
    return [float(np.median(spent)) for spent in times]


def _generator_check(rng) -> float:
    """Largest relative difference of the RK4 generator from the exact ZOH solution (jittered clock)."""
    from motorsim.plant import Motor, simulate
    worst = 0.0
    for a, dt in ((4.0, 0.001), (90.0, 0.02)):
        n = 2000
        t = jittered_times(n, dt, 0.1, rng)
        duty = Sine(min(a, 0.8 * math.pi / dt), 200).duty(n, dt).astype(float)
        ours = rk4_angle(a, _STATIC_GAIN * a, duty, t)
        exact = simulate(Motor(a, _STATIC_GAIN * a), duty, t).angle
        worst = max(worst, float(np.max(np.abs(ours - exact)) / np.max(np.abs(exact))))
    return worst


def _parse(argv: Sequence[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="motorid bench accuracy", description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--sample-periods", type=reals(), default=[0.001, 0.002, 0.005, 0.01, 0.02], metavar="S,S,...",
                   help="sample periods in s, comma-separated (default 0.001,0.002,0.005,0.01,0.02)")
    p.add_argument("--counts", type=integers(), default=[1200, 4096, 16667], metavar="N,N,...",
                   help="encoder resolutions in counts/rev, comma-separated (default 1200,4096,16667)")
    p.add_argument("--poles", type=reals(), default=[4.0, 25.0, 90.0], metavar="A,A,...",
                   help="poles a in 1/s, comma-separated (default 4,25,90)")
    p.add_argument("--ratios", type=reals(), default=[0.3, 1.0, 2.0], metavar="R,R,...",
                   help="sine frequency / a, dimensionless, comma-separated (default 0.3,1,2)")
    p.add_argument("--samples", type=integer(), default=10_000, metavar="N",
                   help="minimum samples per recording (default 10000)")
    p.add_argument("--crb-target", type=real(), default=2.5e-4, metavar="X",
                   help="lengthen a run until its relative CRB of a and b is at most this fraction "
                        "(default 2.5e-4, i.e. 0.025 %%)")
    p.add_argument("--max-samples", type=integer(), default=100_000, metavar="N",
                   help="longest run when lengthening, samples (default 100000)")
    p.add_argument("--friction-samples", type=integer(), default=4000, metavar="N",
                   help="samples per friction run (default 4000)")
    p.add_argument("--repetitions", type=integer(), default=200, metavar="N",
                   help="Monte Carlo repetitions, and runs per regime of the coverage table (default 200)")
    p.add_argument("--coverage-samples", type=integer(), default=2000, metavar="N",
                   help="samples per run of the coverage table (default 2000)")
    p.add_argument("--angle-noise", type=real(positive=False), default=2e-3, metavar="RAD",
                   help="Monte Carlo angle noise in rad (default 0.002)")
    p.add_argument("--repeats", type=integer(), default=15, metavar="N",
                   help="timings of each fit to take the median of (default 15)")
    p.add_argument("--seed", type=integer(0), default=0, help="seed of the noise, jitter and drops (default 0)")
    p.add_argument("--only", choices=["sines", "multisine", "friction", "montecarlo", "timing", "coverage",
                                       "closedloop"],
                   default=None,
                   help="run one section only (default all)")
    return p.parse_args(list(argv))


def bench_accuracy(argv: Sequence[str]) -> int:
    """Run the accuracy benchmark; exit status 0 when every criterion holds."""
    args = _parse(argv)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    print(f"generator: RK4 sub-steps (a*delta <= {_SUBSTEP_AD}); largest relative difference from the exact "
          f"ZOH angle {_generator_check(rng):.1e}")
    ok = True

    def timing() -> bool:          # timings have no criterion
        _section_timing(args)
        return True
    sections = {"sines": lambda: _section_sines(args, rng)[0], "multisine": lambda: _section_multisine(args, rng),
                "friction": lambda: _section_friction(args, rng), "montecarlo": lambda: _section_monte_carlo(args),
                "timing": timing, "coverage": lambda: _section_coverage(args),
                "closedloop": lambda: _section_closed_loop(args)}
    with Ticker("bench accuracy") as ticker:      # on a terminal only, below the tables
        for i, (name, run) in enumerate(sections.items(), 1):
            if args.only in (None, name):
                ticker.set_note(f"section {i} of {len(sections)}: {name}")
                ok &= bool(run())
    print(f"\n{'all criteria hold' if ok else 'SOME CRITERIA FAIL'}  ({time.perf_counter() - t0:.0f} s)")
    return 0 if ok else 1
