"""Values or one-sided limits: what the profiled χ² of one length allows the fit to say.

A 68 % interval closed on both sides inside the allowed range is a
measurement. When it is open on one side (the χ² keeps falling toward the
grid's edge, as for a λ_abs far longer than the distances can resolve), the
fit bounds the length on the other side instead: the one-sided 95 %
confidence limit is where the profiled χ² has risen by 2.71 (1.645²) from
its minimum, times the error scale², as for the intervals. A minimum on an
edge never becomes a value with an error.
"""

from __future__ import annotations

import math

import numpy as np

from analysis.chisq.fit import Objective
from analysis.chisq.results import (
    DCHI2_1D,
    DCHI2_LIMIT_95,
    LOWER_LIMIT,
    MEASURED,
    UNCONSTRAINED,
    UPPER_LIMIT,
    Estimate,
)

#: Confidence level of the one-sided limits.
LIMIT_CL = 0.95


def error_scale(chi2: float, ndof: int) -> float:
    """√(χ²/ndof) when it exceeds 1, else 1 (no scaling of a fit that describes its data)."""
    if ndof <= 0 or not math.isfinite(chi2):
        return 1.0
    return max(1.0, math.sqrt(chi2 / ndof))


def estimate(
    obj: Objective,
    best: np.ndarray,
    k: int,
    name: str,
    chi2_min: float,
    sigma: float,
    scale: float,
) -> tuple[Estimate, tuple[float, float], bool]:
    """The estimate of parameter ``k`` (0: λ_abs, 1: λ_sca) of the objective's minimum ``best``.

    Returns the `Estimate`, the 68 % crossings (metres; an open side sits on
    the range's edge) and whether either crossing reached the edge.
    """
    s2 = scale * scale
    lo, lo_open = obj.crossing(best, k, -1.0, chi2_min + DCHI2_1D * s2, sigma)
    hi, hi_open = obj.crossing(best, k, 1.0, chi2_min + DCHI2_1D * s2, sigma)
    interval = (math.exp(lo), math.exp(hi))
    if not lo_open and not hi_open:
        value = math.exp(float(best[k]))
        est = Estimate(name, MEASURED, value, 0.5 * (interval[1] - interval[0]), interval)
        return est, interval, False
    if lo_open and hi_open:
        return Estimate(name, UNCONSTRAINED, None, None, None), interval, True
    direction = -1.0 if hi_open else 1.0
    x, open_too = obj.crossing(best, k, direction, chi2_min + DCHI2_LIMIT_95 * s2, sigma)
    if open_too:
        return Estimate(name, UNCONSTRAINED, None, None, None), interval, True
    status = LOWER_LIMIT if hi_open else UPPER_LIMIT
    return Estimate(name, status, None, None, None, limit_m=math.exp(x), cl=LIMIT_CL), interval, True
