"""Fits shared by the lab calibrations: weighted straight lines with errors in x and y.

Every calibration of the camera system ends in a straight line: gray against
exposure, log intensity against distance, log total gray against log
distance, disk radius against the inverse distance. One fitter serves them
all, so each reports its errors the same way:

* points are weighted by their *effective* variance
  ``sigma_y**2 + (slope * sigma_x)**2``, so an uncertain distance counts as
  much as an uncertain gray value (the slope is found by iteration);
* parameter errors come from the covariance of the weighted fit and are
  scaled up by ``sqrt(chi2 / ndof)`` when the points scatter more than their
  errors say (the PDG scale factor), never scaled down;
* ``r2`` is the plain coefficient of determination the paper quotes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

ArrayLike = Sequence[float] | np.ndarray


def _as_1d(values: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-D sequence, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


@dataclass(frozen=True)
class LineFit:
    """``y = slope * x + intercept`` fitted by weighted least squares.

    Attributes
    ----------
    x, y, y_err, x_err
        The points fitted and their one-sigma errors.
    slope, slope_err, intercept, intercept_err
        Parameters and their errors (scaled by ``error_scale``).
        ``intercept`` is 0 with error 0 for a fit through the origin.
    cov_slope_intercept
        Covariance of the two parameters (scaled likewise).
    chi2, ndof
        Chi-square of the fit with the effective variances, and its degrees
        of freedom (points minus parameters).
    error_scale
        ``max(1, sqrt(chi2 / ndof))``: the factor applied to the errors.
    r2
        Coefficient of determination, ``1 - SS_res / SS_tot`` (unweighted).
    through_origin
        True when the intercept was fixed at 0.
    """

    x: tuple[float, ...]
    y: tuple[float, ...]
    y_err: tuple[float, ...]
    x_err: tuple[float, ...]
    slope: float
    slope_err: float
    intercept: float
    intercept_err: float
    cov_slope_intercept: float
    chi2: float
    ndof: int
    error_scale: float
    r2: float
    through_origin: bool

    @property
    def chi2_ndof(self) -> float:
        return self.chi2 / self.ndof if self.ndof > 0 else float("nan")

    def predict(self, x: ArrayLike | float) -> np.ndarray:
        """The fitted line at ``x``."""
        return self.slope * np.asarray(x, dtype=np.float64) + self.intercept

    def predict_err(self, x: ArrayLike | float) -> np.ndarray:
        """One-sigma error of the fitted line at ``x`` (from the parameter covariance)."""
        xs = np.asarray(x, dtype=np.float64)
        var = xs * xs * self.slope_err**2 + self.intercept_err**2 + 2.0 * xs * self.cov_slope_intercept
        return np.sqrt(np.maximum(var, 0.0))

    @property
    def residuals(self) -> np.ndarray:
        """Measured minus fitted y at each point."""
        return np.asarray(self.y) - self.predict(self.x)

    @property
    def sigma_eff(self) -> np.ndarray:
        """Effective one-sigma error of each point: y error and x error through the slope."""
        return np.hypot(np.asarray(self.y_err), self.slope * np.asarray(self.x_err))

    @property
    def pulls(self) -> np.ndarray:
        """Residuals in units of the points' effective errors."""
        return self.residuals / self.sigma_eff


def fit_line(
    x: ArrayLike,
    y: ArrayLike,
    y_err: ArrayLike,
    x_err: ArrayLike | None = None,
    *,
    through_origin: bool = False,
    iterations: int = 6,
) -> LineFit:
    """Fit a straight line to points with errors in y (and optionally in x).

    The effective variance ``y_err**2 + (slope * x_err)**2`` depends on the
    slope, so the weighted fit is repeated a few times starting from the fit
    that ignores ``x_err``; for the nearly straight data of a calibration it
    settles after two or three rounds.

    Raises `ValueError` naming the argument for unequal lengths, non-finite
    values, errors that are not > 0, or fewer distinct x values than the
    parameters need.
    """
    xs, ys, ye = _as_1d(x, "x"), _as_1d(y, "y"), _as_1d(y_err, "y_err")
    xe = np.zeros_like(xs) if x_err is None else _as_1d(x_err, "x_err")
    if not (xs.size == ys.size == ye.size == xe.size):
        raise ValueError(
            f"x, y, y_err and x_err must have one length, got {xs.size}, {ys.size}, {ye.size}, {xe.size}"
        )
    if np.any(ye <= 0):
        raise ValueError(f"y_err must be > 0 at every point, got {ye.tolist()}")
    if np.any(xe < 0):
        raise ValueError(f"x_err must be >= 0 at every point, got {xe.tolist()}")
    n_par = 1 if through_origin else 2
    if np.unique(xs).size < n_par or xs.size < n_par:
        raise ValueError(f"a line needs points at >= {n_par} distinct x values, got {np.unique(xs).size}")

    slope = intercept = 0.0
    cov = np.zeros((n_par, n_par))
    var = ye * ye
    for _ in range(max(iterations, 1)):
        w = 1.0 / var
        design = xs[:, None] if through_origin else np.column_stack([xs, np.ones_like(xs)])
        normal = design.T @ (design * w[:, None])
        cov = np.linalg.inv(normal)
        params = cov @ (design.T @ (w * ys))
        slope = float(params[0])
        intercept = 0.0 if through_origin else float(params[1])
        new_var = ye * ye + (slope * xe) ** 2
        if np.allclose(new_var, var, rtol=1e-10, atol=0.0):
            break
        var = new_var

    resid = ys - (slope * xs + intercept)
    chi2 = float(np.sum(resid * resid / var))
    ndof = int(xs.size - n_par)
    scale = max(1.0, math.sqrt(chi2 / ndof)) if ndof > 0 else 1.0
    ss_res = float(np.sum(resid * resid))
    ss_tot = float(np.sum((ys - ys.mean()) ** 2))
    r2 = 1.0 - ss_res / ss_tot if ss_tot > 0 else 1.0
    slope_err = math.sqrt(cov[0, 0]) * scale
    intercept_err = 0.0 if through_origin else math.sqrt(cov[1, 1]) * scale
    cov_si = 0.0 if through_origin else float(cov[0, 1]) * scale * scale
    return LineFit(
        x=tuple(xs.tolist()),
        y=tuple(ys.tolist()),
        y_err=tuple(ye.tolist()),
        x_err=tuple(xe.tolist()),
        slope=slope,
        slope_err=slope_err,
        intercept=intercept,
        intercept_err=intercept_err,
        cov_slope_intercept=cov_si,
        chi2=chi2,
        ndof=ndof,
        error_scale=scale,
        r2=r2,
        through_origin=through_origin,
    )


@dataclass(frozen=True)
class Combined:
    """Repeated measurements of one quantity reduced to a mean and its error.

    ``err`` is the larger of the scatter of the values over ``sqrt(n)`` and
    the single errors propagated, the rule `analysis.stack` uses for stacked
    frames: the scatter catches what the single errors miss (flicker, small
    moves), the propagation keeps a small set from claiming a lucky scatter.
    """

    mean: float
    err: float
    n: int
    scatter: float


def combine_repeats(values: ArrayLike, errors: ArrayLike) -> Combined:
    """Mean of repeated values with the error rule of `Combined`."""
    v, e = _as_1d(values, "values"), _as_1d(errors, "errors")
    if v.size == 0 or v.size != e.size:
        raise ValueError(f"values and errors must be non-empty and of one length, got {v.size} and {e.size}")
    n = int(v.size)
    propagated = float(math.sqrt(np.sum(e * e)) / n)
    scatter = float(v.std(ddof=1)) if n >= 2 else 0.0
    return Combined(float(v.mean()), max(scatter / math.sqrt(n), propagated), n, scatter)


@dataclass(frozen=True)
class WeightedMean:
    """Inverse-variance weighted mean; ``err`` scaled by ``max(1, sqrt(chi2/ndof))``."""

    mean: float
    err: float
    chi2_ndof: float
    n: int


def weighted_mean(values: ArrayLike, errors: ArrayLike) -> WeightedMean:
    """Weighted mean of independent measurements, with the PDG scale factor on its error."""
    v, e = _as_1d(values, "values"), _as_1d(errors, "errors")
    if v.size == 0 or v.size != e.size:
        raise ValueError(f"values and errors must be non-empty and of one length, got {v.size} and {e.size}")
    if np.any(e <= 0):
        raise ValueError(f"errors must be > 0, got {e.tolist()}")
    w = 1.0 / (e * e)
    mean = float(np.sum(w * v) / np.sum(w))
    err = float(1.0 / math.sqrt(np.sum(w)))
    n = int(v.size)
    chi2_ndof = float(np.sum(w * (v - mean) ** 2) / (n - 1)) if n > 1 else float("nan")
    if n > 1:
        err *= max(1.0, math.sqrt(chi2_ndof))
    return WeightedMean(mean, err, chi2_ndof, n)
