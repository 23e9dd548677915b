"""Linear response calibration: where the camera's gray values stay proportional to light.

In a darkroom a steady source is photographed at a fixed gain with exposures
from 1 ms to 350 ms (and at a fixed exposure with a range of gains). The
light collected is proportional to the exposure (to the linear gain factor),
so the mean gray of the same pixels should follow a straight line until the
sensor compresses and clips. This module finds that line and where the
response leaves it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.calibration.fit import ArrayLike, LineFit, fit_line

#: A centre mean at or above this gray is clipped by the ADC: never part of a linear run.
CLIPPED_GRAY = 254.0


@dataclass(frozen=True)
class ResponseCurve:
    """The camera's response along one sweep and its linear part.

    Attributes
    ----------
    sweep
        ``"exposure"`` (x in seconds, gain fixed) or ``"gain"`` (x the linear
        gain factor ``10 ** (gain_db / 20)``, exposure fixed).
    fixed
        The setting held fixed: gain in dB for an exposure sweep, exposure in
        seconds for a gain sweep.
    x, gray, gray_err, n_frames
        The sweep's points in increasing x: mean gray of the same pixels, its
        one-sigma error and the number of frames averaged.
    linear
        Per point: True if it lies in the linear range (within the tolerance
        of the line).
    fitted
        Per point: True if the line was fitted to it (a run that agrees with
        the line within its errors alone; inside the linear range).
    fit
        ``gray = slope * x + intercept`` over the fitted points. The slope is
        in gray per second (exposure sweep) or gray per unit gain factor;
        the intercept is the dark level (gray at zero light).
    linear_range_gray
        ``(low, high)``: the lowest and highest mean gray of the linear
        range, the range the measurement shows to be linear (the recommendation).
    departure_gray, departure_err_gray, departure_x
        The gray (as measured) at which the response first deviates from the
        line by ``tolerance`` of the signal, interpolated between the last
        linear point and the first one above it; the error is that bracket's
        width over sqrt(12). None when the sweep never leaves the line.
    tolerance, n_sigma
        A point is in the linear range unless it misses the line by more
        than ``tolerance`` of the signal above the dark level plus
        ``n_sigma`` errors: only a deviation significantly beyond the
        tolerance counts, so noise alone never ends the range.
    """

    sweep: str
    fixed: float
    x: tuple[float, ...]
    gray: tuple[float, ...]
    gray_err: tuple[float, ...]
    n_frames: tuple[int, ...]
    linear: tuple[bool, ...]
    fitted: tuple[bool, ...]
    fit: LineFit
    linear_range_gray: tuple[float, float]
    departure_gray: float | None
    departure_err_gray: float | None
    departure_x: float | None
    tolerance: float
    n_sigma: float

    @property
    def relative_residuals(self) -> np.ndarray:
        """(gray - line) / (line - dark level) at every point of the sweep."""
        pred = self.fit.predict(self.x)
        return (np.asarray(self.gray) - pred) / np.maximum(pred - self.fit.intercept, 1e-12)


def _run_is_linear(
    x: np.ndarray, g: np.ndarray, e: np.ndarray, tolerance: float, n_sigma: float
) -> LineFit | None:
    """The line through a run of points if every point agrees with it, else None."""
    try:
        fit = fit_line(x, g, e)
    except ValueError:
        return None
    if not fit.slope > n_sigma * fit.slope_err:
        return None  # no response: a flat run (e.g. clipped points) is not "linear"
    pred = fit.predict(x)
    signal = pred - fit.intercept
    dev = np.abs(g - pred)
    ok = dev <= tolerance * np.abs(signal) + n_sigma * e
    return fit if bool(np.all(ok)) else None


def _longest_run(
    xs: np.ndarray,
    gs: np.ndarray,
    es: np.ndarray,
    usable: np.ndarray,
    tolerance: float,
    n_sigma: float,
    min_points: int,
) -> tuple[int, int, LineFit] | None:
    """The longest contiguous run of usable points that agree with their own line (ties: lower chi2)."""
    best: tuple[int, int, LineFit] | None = None
    n = xs.size
    for i in range(n):
        for j in range(i + min_points - 1, n):
            if not usable[i : j + 1].all():
                break
            if best is not None and (j - i) < (best[1] - best[0]):
                continue
            fit = _run_is_linear(xs[i : j + 1], gs[i : j + 1], es[i : j + 1], tolerance, n_sigma)
            if fit is None:
                continue
            if best is None or (j - i) > (best[1] - best[0]) or fit.chi2_ndof < best[2].chi2_ndof:
                best = (i, j, fit)
    return best


#: An end point of the fitted run that its neighbours' line misses by more
#: than this many sigma is trimmed: the ends are where a sensor bends.
END_SIGMA = 2.0


def _trim_ends(
    xs: np.ndarray,
    gs: np.ndarray,
    es: np.ndarray,
    i: int,
    j: int,
    fit: LineFit,
    *,
    min_points: int,
    end_sigma: float,
) -> tuple[int, int, LineFit]:
    """Drop end points of the run ``[i, j]`` that the line through the rest predicts badly.

    Inside a run every point agrees with the run's line within 3 sigma, but
    a point just under the knee, compressed by 2-3 sigma, pulls the line
    (the slope by about its own error). Each end is tested against the
    line of the other points, prediction error included, and dropped
    beyond ``end_sigma``; repeated until both ends hold.
    """
    changed = True
    while changed and j - i + 1 > min_points:
        changed = False
        for end in (j, i):
            rest = slice(i, j) if end == j else slice(i + 1, j + 1)
            line = fit_line(xs[rest], gs[rest], es[rest])
            pred, pred_err = float(line.predict(xs[end])), float(line.predict_err(xs[end]))
            if abs(gs[end] - pred) > end_sigma * math.hypot(es[end], pred_err):
                i, j = (i, j - 1) if end == j else (i + 1, j)
                fit, changed = line, True
                break
    return i, j, fit


def response_linearity(
    x: ArrayLike,
    gray: ArrayLike,
    gray_err: ArrayLike,
    *,
    sweep: str,
    fixed: float,
    n_frames: ArrayLike | None = None,
    tolerance: float = 0.01,
    n_sigma: float = 3.0,
    min_points: int = 3,
) -> ResponseCurve:
    """Fit the linear part of a response sweep and find where it ends.

    Steps:

    1. sort the points by x; points whose mean is clipped (>= 254 gray) can
       bracket the departure but never belong to the line;
    2. the line: among all contiguous runs of at least ``min_points``
       points, the longest whose every point agrees with the run's own
       weighted line within ``n_sigma`` errors, with a significantly positive
       slope; then its end points are trimmed while the line through the
       others misses them by more than `END_SIGMA` (`_trim_ends`). Taking
       the longest run rather than assuming a range lets the data say where
       the response is straight; requiring agreement within the errors
       keeps slightly compressed points out of the slope and the dark
       level. (If noise leaves no such run, the tolerance is allowed here too.);
    3. the linear range: from that run outward, every neighbour within
       ``tolerance`` of the signal above the dark level (plus ``n_sigma``
       errors of point and line) joins, up and down, until one does not;
    4. the first point above the range brackets the departure: the relative
       deviation is interpolated linearly to ``tolerance`` between it and the
       range's last point. The deviation grows faster than linearly above a
       knee, so the estimate errs low: on the cautious side.
    """
    if sweep not in ("exposure", "gain"):
        raise ValueError(f"sweep must be 'exposure' or 'gain', got {sweep!r}")
    if not (0 < tolerance < 1):
        raise ValueError(f"tolerance must lie in (0, 1), got {tolerance}")
    if min_points < 3:
        raise ValueError(f"min_points must be >= 3, got {min_points}")
    xs, gs, es = (np.asarray(v, dtype=np.float64) for v in (x, gray, gray_err))
    ns = np.ones(xs.size, dtype=int) if n_frames is None else np.asarray(n_frames, dtype=int)
    if not (xs.shape == gs.shape == es.shape == ns.shape) or xs.ndim != 1:
        raise ValueError("x, gray, gray_err and n_frames must be 1-D and of one length")
    if np.unique(xs).size != xs.size:
        raise ValueError("x must hold one point per setting (average repeats first)")
    order = np.argsort(xs)
    xs, gs, es, ns = xs[order], gs[order], es[order], ns[order]
    usable = gs < CLIPPED_GRAY
    if int(usable.sum()) < min_points:
        raise ValueError(
            f"{sweep} sweep: {int((~usable).sum())} of {xs.size} settings are clipped at 255; "
            f"a line needs >= {min_points} unclipped settings"
        )
    best = _longest_run(xs, gs, es, usable, 0.0, n_sigma, min_points)
    best = best or _longest_run(xs, gs, es, usable, tolerance, n_sigma, min_points)
    if best is None:
        raise ValueError(
            f"{sweep} sweep: no {min_points} consecutive settings respond linearly "
            f"(within {100 * tolerance:g} % + {n_sigma:g} sigma)"
        )
    i, j, fit = _trim_ends(xs, gs, es, *best, min_points=min_points, end_sigma=END_SIGMA)
    fitted = np.zeros(xs.size, dtype=bool)
    fitted[i : j + 1] = True

    def agrees(k: int) -> bool:
        pred = float(fit.predict(xs[k]))
        margin = tolerance * abs(pred - fit.intercept) + n_sigma * math.hypot(
            es[k], float(fit.predict_err(xs[k]))
        )
        return bool(usable[k]) and abs(gs[k] - pred) <= margin

    lo, hi = i, j
    while lo > 0 and agrees(lo - 1):
        lo -= 1
    while hi + 1 < xs.size and agrees(hi + 1):
        hi += 1
    linear = np.zeros(xs.size, dtype=bool)
    linear[lo : hi + 1] = True

    departure = departure_err = departure_x = None
    if hi + 1 < xs.size:
        pred = fit.predict(xs[hi : hi + 2])
        signal = np.maximum(pred - fit.intercept, 1e-12)
        dev = np.abs(gs[hi : hi + 2] - pred) / signal
        d_lo, d_hi = float(dev[0]), float(dev[1])
        t = (tolerance - d_lo) / (d_hi - d_lo) if d_hi > d_lo else 1.0
        t = min(max(t, 0.0), 1.0)
        g_lo, g_hi = float(gs[hi]), float(gs[hi + 1])
        departure = g_lo + t * (g_hi - g_lo)
        departure_x = float(xs[hi] + t * (xs[hi + 1] - xs[hi]))
        departure_err = abs(g_hi - g_lo) / math.sqrt(12.0)
    return ResponseCurve(
        sweep=sweep,
        fixed=float(fixed),
        x=tuple(xs.tolist()),
        gray=tuple(gs.tolist()),
        gray_err=tuple(es.tolist()),
        n_frames=tuple(int(v) for v in ns),
        linear=tuple(bool(v) for v in linear),
        fitted=tuple(bool(v) for v in fitted),
        fit=fit,
        linear_range_gray=(float(gs[lo]), float(gs[hi])),
        departure_gray=departure,
        departure_err_gray=departure_err,
        departure_x=departure_x,
        tolerance=tolerance,
        n_sigma=n_sigma,
    )
