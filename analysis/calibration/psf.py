"""The point spread function from frames of a point-like source: the focus check.

A source much smaller than a pixel's field of view images as the PSF
itself. The PSF is modelled, as in the chi-square analysis, as a 2-D
Gaussian; each pixel collects the Gaussian integrated over its area, so the
fitted width is the optical blur alone, not blur plus pixel size. (Fitting
pixel-centre samples instead would return sqrt(sigma² + 1/12) for a sharp
image.) The axes are those of the sensor: astigmatism shows as
``sigma_x != sigma_y``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.special import erf

from analysis.calibration.fit import Combined, combine_repeats
from analysis.detect import check_frame

#: FWHM of a Gaussian in units of its sigma: 2 sqrt(2 ln 2).
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


def pixel_integrated_gaussian(
    cols: np.ndarray, rows: np.ndarray, x0: float, y0: float, sigma_x: float, sigma_y: float
) -> np.ndarray:
    """Fraction of a unit 2-D Gaussian falling on each pixel ``[rows, cols]``.

    Pixel ``[r, c]`` covers ``[c - 0.5, c + 0.5] x [r - 0.5, r + 0.5]``
    (``docs/conventions.md``); the Gaussian separates into erf differences.
    """
    sx, sy = math.sqrt(2.0) * sigma_x, math.sqrt(2.0) * sigma_y
    fx = 0.5 * (erf((cols + 0.5 - x0) / sx) - erf((cols - 0.5 - x0) / sx))
    fy = 0.5 * (erf((rows + 0.5 - y0) / sy) - erf((rows - 0.5 - y0) / sy))
    return fy[:, None] * fx[None, :]


@dataclass(frozen=True)
class PointSourceFit:
    """Pixel-integrated Gaussian + constant fitted to a window around a point source.

    Positions are frame coordinates (x, y) of the Gaussian's centre; the
    widths are one-sigma in pixels; ``flux_gray`` is the total gray above
    ``background_gray``. Errors come from the covariance of the weighted
    fit, scaled up by sqrt(``chi2_ndof``) if that exceeds 1. For a PSF of
    sigma below ~1 px a handful of pixels carry the shot noise and the
    noise model, fitted to the frame itself, sees it poorly: single-frame
    errors then run low by up to 1.5x (simulated). `psf_width` therefore
    uses the frame-to-frame scatter whenever it is larger. ``peak_gray`` is
    the brightest pixel of the window.
    """

    x_px: float
    y_px: float
    sigma_x_px: float
    sigma_x_err_px: float
    sigma_y_px: float
    sigma_y_err_px: float
    flux_gray: float
    flux_err_gray: float
    background_gray: float
    peak_gray: float
    residual_rms_gray: float
    chi2_ndof: float
    window_px: int

    @property
    def sigma_px(self) -> float:
        """Round-equivalent width: the geometric mean of the two axes."""
        return math.sqrt(self.sigma_x_px * self.sigma_y_px)


def fit_point_source(
    frame: np.ndarray, center_xy: tuple[float, float], half_size_px: int = 8
) -> PointSourceFit:
    """Fit the PSF to the ``(2 * half_size_px + 1)²`` window around ``center_xy``.

    Starting values: the window's moments for centre and widths, its edge
    median for the background. `scipy.optimize.least_squares` (trust region,
    widths kept in 0.1..half_size_px) fits all six parameters, first
    unweighted, then twice weighted by a noise model (variance linear in
    the signal: read noise plus shot noise) fitted to the previous pass's
    leverage-corrected residuals. The window must lie inside the frame.
    """
    frame = check_frame(frame)
    if half_size_px < 3:
        raise ValueError(f"half_size_px must be >= 3, got {half_size_px}")
    cx, cy = round(center_xy[0]), round(center_xy[1])
    h = int(half_size_px)
    height, width = frame.shape
    if cx - h < 0 or cy - h < 0 or cx + h >= width or cy + h >= height:
        raise ValueError(f"center_xy {center_xy}: the {2 * h + 1} px window leaves the frame")
    win = frame[cy - h : cy + h + 1, cx - h : cx + h + 1].astype(np.float64)
    cols = np.arange(cx - h, cx + h + 1, dtype=np.float64)
    rows = np.arange(cy - h, cy + h + 1, dtype=np.float64)
    edge = np.concatenate([win[0], win[-1], win[1:-1, 0], win[1:-1, -1]])
    bg0 = float(np.median(edge))
    signal = np.clip(win - bg0, 0, None)
    flux0 = float(signal.sum()) or 1.0
    x0 = float((signal.sum(axis=0) * cols).sum() / flux0)
    y0 = float((signal.sum(axis=1) * rows).sum() / flux0)
    sx0 = math.sqrt(max(float((signal.sum(axis=0) * (cols - x0) ** 2).sum() / flux0), 0.25))
    sy0 = math.sqrt(max(float((signal.sum(axis=1) * (rows - y0) ** 2).sum() / flux0), 0.25))

    def model(p: np.ndarray) -> np.ndarray:
        return p[4] * pixel_integrated_gaussian(cols, rows, p[0], p[1], p[2], p[3]) + p[5]

    start = np.array([x0, y0, min(sx0, h - 0.5), min(sy0, h - 0.5), flux0, bg0])
    lower = [cx - h, cy - h, 0.1, 0.1, 0.0, -np.inf]
    upper = [cx + h, cy + h, float(h), float(h), np.inf, np.inf]
    # Pass 1 is unweighted; passes 2 and 3 are weighted by a noise model
    # fitted to the previous pass's residuals: variance = read + gain * signal,
    # since the peak pixels carry shot noise the dark ones lack. The few
    # core pixels steer the fit, which pulls their residuals toward zero:
    # each squared residual is divided by 1 - its leverage before the
    # regression, or the shot noise (and with it every error) comes out low.
    sigma = np.ones_like(win)
    p = start
    for _ in range(3):
        res = least_squares(
            lambda q, s=sigma: ((model(q) - win) / s).ravel(),
            p,
            bounds=(lower, upper),
            x_scale="jac",
        )
        p = res.x
        jac = res.jac
        leverage = np.einsum("ij,jk,ik->i", jac, np.linalg.pinv(jac.T @ jac), jac)
        r2 = ((model(p) - win) ** 2).ravel() / np.clip(1.0 - leverage, 0.05, None)
        signal = np.clip(model(p) - p[5], 0.0, None)
        design = np.column_stack([np.ones(signal.size), signal.ravel()])
        (var0, slope), *_ = np.linalg.lstsq(design, r2, rcond=None)
        var0 = max(float(var0), 1.0 / 12.0)  # never below the quantisation noise
        sigma = np.sqrt(var0 + max(float(slope), 0.0) * signal)
    dof = max(win.size - p.size, 1)
    chi2_ndof = float(np.sum(res.fun**2) / dof)
    cov = np.linalg.pinv(res.jac.T @ res.jac) * max(chi2_ndof, 1.0)
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    resid_rms = float(np.sqrt(np.mean((model(p) - win) ** 2)))
    return PointSourceFit(
        x_px=float(p[0]),
        y_px=float(p[1]),
        sigma_x_px=float(p[2]),
        sigma_x_err_px=float(err[2]),
        sigma_y_px=float(p[3]),
        sigma_y_err_px=float(err[3]),
        flux_gray=float(p[4]),
        flux_err_gray=float(err[4]),
        background_gray=float(p[5]),
        peak_gray=float(win.max()),
        residual_rms_gray=resid_rms,
        chi2_ndof=chi2_ndof,
        window_px=2 * h + 1,
    )


@dataclass(frozen=True)
class PSFResult:
    """The PSF width from several frames.

    ``sigma_x``, ``sigma_y`` and ``sigma`` (round-equivalent) combine the
    frames' fits by `combine_repeats`: the frame-to-frame scatter over sqrt(n)
    or the fit errors propagated, whichever is larger. ``fwhm_px`` is
    ``FWHM_PER_SIGMA * sigma``.
    """

    sigma: Combined
    sigma_x: Combined
    sigma_y: Combined

    @property
    def fwhm_px(self) -> float:
        return FWHM_PER_SIGMA * self.sigma.mean

    @property
    def fwhm_err_px(self) -> float:
        return FWHM_PER_SIGMA * self.sigma.err

    @property
    def ellipticity(self) -> float:
        """``1 - minor / major`` of the mean widths; 0 for a round PSF."""
        a, b = self.sigma_x.mean, self.sigma_y.mean
        return 1.0 - min(a, b) / max(a, b)


def psf_width(
    sigma_x_px: Sequence[float],
    sigma_x_err_px: Sequence[float],
    sigma_y_px: Sequence[float],
    sigma_y_err_px: Sequence[float],
) -> PSFResult:
    """Combine the point-source fits of several frames (their widths and errors) into one PSF width."""
    if not sigma_x_px:
        raise ValueError("sigma_x_px is empty: no usable point-source frame")
    sx_v, sx_e = np.asarray(sigma_x_px, dtype=float), np.asarray(sigma_x_err_px, dtype=float)
    sy_v, sy_e = np.asarray(sigma_y_px, dtype=float), np.asarray(sigma_y_err_px, dtype=float)
    sx, sy = combine_repeats(sx_v, sx_e), combine_repeats(sy_v, sy_e)
    round_v = np.sqrt(sx_v * sy_v)
    round_e = 0.5 * round_v * np.hypot(sx_e / sx_v, sy_e / sy_v)
    return PSFResult(combine_repeats(round_v, round_e), sx, sy)


def psf_width_of(fits: Sequence[PointSourceFit]) -> PSFResult:
    """`psf_width` of a sequence of `PointSourceFit`."""
    return psf_width(
        [f.sigma_x_px for f in fits],
        [f.sigma_x_err_px for f in fits],
        [f.sigma_y_px for f in fits],
        [f.sigma_y_err_px for f in fits],
    )
