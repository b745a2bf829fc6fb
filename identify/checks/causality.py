"""Whether the output answers its recorded input before that input: an input logged late.

A first-order motor cannot answer an input it has not received.  When the duty column is logged
one sample after the duty was applied (a logger that writes the new duty with the next sample),
the speed changes one sample before the recorded input does: a negative input delay, which no
estimator tries.  Fitted at delay 0, such data give a confident, wrong ``a`` (25 becomes 28.6 on
the article's sine, with an interval that excludes 25).

:func:`check_input_leads` fits ``oe`` twice on the longest gap-free stretch of each recording
(its first :data:`LEAD_ROWS` rows): as recorded, and with the input moved one sample earlier, both
at the delay the recording declares (``input_delay_samples``, else 0).  When the earlier input
fits better beyond the noise (the comparison of :mod:`identify.comparison`, at level
:data:`LEAD_LEVEL`), materially (:data:`MATERIAL`) and to white residuals (:data:`WHITE_LAGS`: the
shifted input explains the data, not some other misfit), the data are refused, saying so.
"""
from __future__ import annotations

import dataclasses
from typing import NamedTuple, Sequence

import numpy as np

from motorsim.recording import Recording

from ..data import declared_input_delay
from ..errors import NotIdentifiableError

__all__ = ["check_input_leads", "input_lead_test", "LeadTest", "LEAD_ROWS", "LEAD_LEVEL", "MATERIAL", "WHITE_LAGS"]

#: Rows of each recording the two fits use (the first of its longest gap-free stretch).
LEAD_ROWS = 20_000
#: Level of the test that calls the earlier input better: strict, since a refusal stops the fit.
LEAD_LEVEL = 1e-3
#: And by how much, at least: its residual RMS at most this share of the recorded input's.  The test
#: alone takes the rounding of a coarse encoder (44 counts/rev) for noise that a shift can explain
#: (residuals 0.041 against 0.041 rad called different); a late log shrinks the residual by 15 % even
#: under 2 mrad of angle noise, and tenfold on a clean encoder.
MATERIAL = 0.9
#: Lags of the whiteness test the earlier input's residuals must pass (a chi-square on as many degrees
#: of freedom, at :data:`LEAD_LEVEL`): a model that is wrong in another way (strong Coulomb friction
#: fitted linearly) can fit better with a shifted input too, but leaves structure in its residuals.
WHITE_LAGS = 10


def _residuals(rec: Recording, delay: int) -> np.ndarray | None:
    from ..fits.output_error import fit_output_error
    from .validation import model_residuals
    try:
        est = fit_output_error(rec, input_delay=delay)
        return model_residuals(est, rec)[0]
    except (NotIdentifiableError, ValueError):
        return None


class LeadTest(NamedTuple):
    """The comparison of one recording: the statistic, both fits' residual RMS and the earlier one's whiteness."""

    statistic: float
    rms_recorded: float
    rms_earlier: float
    whiteness: float

    def leads(self) -> bool:
        """Whether the earlier input fits better beyond the noise, materially, and to white residuals."""
        from scipy.special import chdtri, fdtri

        from ..comparison import BLOCKS
        return (self.statistic > float(fdtri(1, BLOCKS - 1, 1.0 - LEAD_LEVEL))
                and self.rms_earlier <= MATERIAL * self.rms_recorded
                and self.whiteness < float(chdtri(WHITE_LAGS, LEAD_LEVEL)))


def input_lead_test(rec: Recording) -> LeadTest:
    """:class:`LeadTest` on the longest gap-free stretch of ``rec`` (all zero when it is too short or a fit fails).

    Found once per recording (it never changes) and kept with it: every fit of the same recording, by
    each method of a sweep or each timing of a benchmark, asks again, and the test is two ``oe`` fits.
    """
    found = rec.__dict__.get("_input_lead")
    if found is None:
        found = _input_lead_test(rec)
        object.__setattr__(rec, "_input_lead", found)
    return found


def _input_lead_test(rec: Recording) -> LeadTest:
    from ..comparison import statistic
    from .validation import autocorrelation
    none = LeadTest(0.0, 0.0, 0.0, 0.0)
    seg = max(rec.segments(), key=len)
    n = min(len(seg), LEAD_ROWS + 1)
    if n < 50:
        return none
    seg = seg.slice(0, n)
    recorded = seg.slice(0, n - 1)
    earlier = dataclasses.replace(seg, duty=np.concatenate([seg.duty[1:], seg.duty[-1:]])).slice(0, n - 1)
    delay = declared_input_delay(rec)
    r0, r1 = _residuals(recorded, delay), _residuals(earlier, delay)
    if r0 is None or r1 is None or len(r0) != len(r1):
        return none
    s0, s1 = float(r0 @ r0), float(r1 @ r1)
    rho = autocorrelation(r1, WHITE_LAGS)[1:]
    whiteness = len(r1) * float(np.sum(rho ** 2)) if np.all(np.isfinite(rho)) else np.inf
    t = statistic(r0 - r1, s0 - s1, r1) if s1 < s0 else 0.0
    return LeadTest(t, (s0 / len(r0)) ** 0.5, (s1 / len(r1)) ** 0.5, whiteness)


def check_input_leads(recordings: Sequence[Recording], names: Sequence[str] | None = None) -> None:
    """Refuse recordings whose output answers the input one sample before it was recorded.

    Parameters
    ----------
    recordings : sequence of Recording
        The runs to fit.
    names : sequence of str, optional
        How to name each run in the message (default its file, else ``recordings[i]``).

    Raises
    ------
    NotIdentifiableError
        Naming the run, both fits' residuals and what to fix.
    """
    for i, rec in enumerate(recordings):
        test = input_lead_test(rec)
        rms0, rms1 = test.rms_recorded, test.rms_earlier
        if test.leads():
            name = names[i] if names is not None else rec.name(i)
            unit = "rad" if rec.angle is not None or rec.counts is not None else "rad/s"
            delay = declared_input_delay(rec)
            declared = f" (input_delay_samples {delay} declared)" if delay else ""
            raise NotIdentifiableError(
                f"{name}: the output answers its recorded input one sample before it{declared}: with the input "
                f"one sample earlier the fit's residual is {rms1:.3g} {unit} RMS against {rms0:.3g} {unit} as "
                "recorded, beyond the noise; the input column is likely logged one sample late (a negative "
                "input delay, which no model has): shift it one row earlier (motorid import or identify "
                "--input-shift 1), or fix the logging")
