"""Camera linearity: gray against exposure (fixed gain) or against linear gain."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


def gain_factor(gain_db: float | np.ndarray) -> float | np.ndarray:
    """Linear amplitude factor of a gain in dB: ``10 ** (gain_db / 20)``."""
    return 10.0 ** (np.asarray(gain_db, dtype=np.float64) / 20.0)


@dataclass(frozen=True)
class LinearityResult:
    """Straight-line fit ``gray = slope * x + intercept`` over the linear points.

    ``x`` is the exposure in seconds (or the linear gain factor). ``r2`` is the
    coefficient of determination over the points used. ``linear_max_gray`` is
    the highest measured gray that still lies within ``tolerance`` of the line;
    ``knee_x`` the first x whose gray leaves the line (None if none does):
    where saturation sets in.
    """

    slope: float
    slope_err: float
    intercept_gray: float
    intercept_err_gray: float
    r2: float
    n_points: int
    n_used: int
    linear_max_gray: float
    knee_x: float | None
    knee_gray: float | None
    tolerance: float
    x: tuple[float, ...]
    gray: tuple[float, ...]
    used: tuple[bool, ...]


def linearity_fit(
    x: Sequence[float] | np.ndarray,
    gray: Sequence[float] | np.ndarray,
    linear_range_gray: tuple[float, float] = (5.0, 240.0),
    tolerance: float = 0.03,
) -> LinearityResult:
    """Fit the linear part of a response curve and find where it ends.

    Points with gray inside ``linear_range_gray`` define the line (by least
    squares). Walking up in x, the first point whose gray falls short of (or
    exceeds) the line by more than ``tolerance`` of the predicted value marks
    the knee: above it the sensor saturates.
    """
    xs = np.asarray(x, dtype=np.float64)
    ys = np.asarray(gray, dtype=np.float64)
    if xs.shape != ys.shape or xs.ndim != 1:
        raise ValueError("x and gray must be 1-D sequences of equal length")
    order = np.argsort(xs, kind="stable")
    xs, ys = xs[order], ys[order]
    ok = np.isfinite(xs) & np.isfinite(ys)
    lo, hi = linear_range_gray
    used = ok & (ys >= lo) & (ys <= hi)
    if np.unique(xs[used]).size < 2:
        raise ValueError(
            f"linearity needs points at >= 2 distinct settings with gray in [{lo:g}, {hi:g}]; "
            f"got {int(used.sum())} point(s)"
        )
    A = np.vstack([xs[used], np.ones(int(used.sum()))]).T
    (slope, intercept), *_ = np.linalg.lstsq(A, ys[used], rcond=None)
    pred = slope * xs + intercept
    resid = ys[used] - pred[used]
    ss_res = float(np.sum(resid**2))
    ss_tot = float(np.sum((ys[used] - ys[used].mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    n_used = int(used.sum())
    if n_used > 2:
        s2 = ss_res / (n_used - 2)
        cov = s2 * np.linalg.inv(A.T @ A)
        slope_err, intercept_err = math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])
    else:
        slope_err = intercept_err = float("nan")
    knee_x = knee_gray = None
    linear_max = float(np.max(ys[used]))
    for xi, yi, pi in zip(xs[ok], ys[ok], pred[ok], strict=True):
        if pi <= 0:
            continue
        if abs(yi - pi) > tolerance * pi and yi > lo:
            if yi >= linear_max or pi > hi:
                knee_x, knee_gray = float(xi), float(pi)
                break
        elif yi > linear_max:
            linear_max = float(yi)
    return LinearityResult(
        slope=float(slope),
        slope_err=slope_err,
        intercept_gray=float(intercept),
        intercept_err_gray=intercept_err,
        r2=r2,
        n_points=int(ok.sum()),
        n_used=n_used,
        linear_max_gray=linear_max,
        knee_x=knee_x,
        knee_gray=knee_gray,
        tolerance=tolerance,
        x=tuple(float(v) for v in xs),
        gray=tuple(float(v) for v in ys),
        used=tuple(bool(u) for u in used),
    )
