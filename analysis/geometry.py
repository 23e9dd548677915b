"""LEM radius by Hough circle and the pinhole check (radius x distance constant)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

#: Radius of the T-REX LEM sphere (0.43 m diameter).
LEM_RADIUS_M = 0.215


def hough_radius_px(pixels: np.ndarray, expected_radius_px: float) -> tuple[float, float, float] | None:
    """Circle fit of the LEM's edge: ``(x_px, y_px, radius_px)`` or None.

    The image (a crop; NaN outside the frame counts as dark) is scaled to
    8 bits and smoothed, then `cv2.HoughCircles` searches radii within ±40 %
    of ``expected_radius_px`` (the equal-area radius from the detection).
    """
    img = np.nan_to_num(np.asarray(pixels, dtype=np.float32), nan=0.0)
    lo, hi = float(np.percentile(img, 5)), float(img.max())
    if hi <= lo:
        return None
    img8 = np.clip((img - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)
    img8 = cv2.GaussianBlur(img8, (5, 5), 1.5)
    r_min = max(int(expected_radius_px * 0.6), 2)
    r_max = max(math.ceil(expected_radius_px * 1.4), r_min + 2)
    circles = cv2.HoughCircles(
        img8,
        cv2.HOUGH_GRADIENT_ALT,
        dp=1.0,
        minDist=max(img8.shape),
        param1=60,
        param2=0.6,
        minRadius=r_min,
        maxRadius=r_max,
    )
    if circles is None or len(circles) == 0:
        return None
    x, y, r = (float(v) for v in circles[0][0])
    return x, y, r


@dataclass(frozen=True)
class PinholeCheck:
    """Fit of ``radius_px = k / distance_m``.

    For a pinhole camera ``k = f_px * LEM radius``, so ``focal_px`` follows.
    ``max_rel_residual`` is the largest relative deviation of a measured
    radius from the fit; a few percent confirms the pinhole model.
    """

    k_px_m: float
    k_err_px_m: float
    focal_px: float
    max_rel_residual: float
    residuals_px: tuple[float, ...]
    distances_m: tuple[float, ...]
    radii_px: tuple[float, ...]


def pinhole_check(
    distances_m: Sequence[float], radii_px: Sequence[float], lem_radius_m: float = LEM_RADIUS_M
) -> PinholeCheck:
    """Fit radius = k/L by least squares in 1/L (one parameter)."""
    d = np.asarray(distances_m, dtype=np.float64)
    r = np.asarray(radii_px, dtype=np.float64)
    if d.size < 2 or d.shape != r.shape:
        raise ValueError("pinhole check needs >= 2 (distance, radius) pairs of equal length")
    if np.any(d <= 0) or np.any(r <= 0):
        raise ValueError("distances and radii must be > 0")
    u = 1.0 / d
    k = float(np.sum(u * r) / np.sum(u * u))
    resid = r - k * u
    dof = max(d.size - 1, 1)
    k_err = float(math.sqrt(np.sum(resid**2) / dof / np.sum(u * u)))
    return PinholeCheck(
        k_px_m=k,
        k_err_px_m=k_err,
        focal_px=k / lem_radius_m,
        max_rel_residual=float(np.max(np.abs(resid) / r)),
        residuals_px=tuple(float(v) for v in resid),
        distances_m=tuple(float(v) for v in d),
        radii_px=tuple(float(v) for v in r),
    )
