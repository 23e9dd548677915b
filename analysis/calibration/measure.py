"""What the lab calibrations measure on one frame.

* `measure_source`: the I_center analysis of `analysis.frame.analyze_frame`
  plus the total gray of the source (an aperture sum above the fitted
  background) and its radius by Hough circle;
* `gray_at`: the mean gray of the same pixels in every frame of a darkroom
  sweep, where the source does not move.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from analysis.detect import check_frame
from analysis.frame import FrameAnalysis, FrameConfig, analyze_frame
from analysis.geometry import hough_radius_px
from analysis.profile import DEFAULT_CENTER_PIXELS, CenterValue, Crop, center_value


def aperture_radius_px(radius_px: float) -> float:
    """Radius of the aperture that holds all of a disk's light: its blurred edge and a margin."""
    return 1.25 * radius_px + 8.0


@dataclass(frozen=True)
class ApertureSum:
    """Total gray inside a circular aperture, above the background.

    ``total_err_gray`` adds the error of the background times the pixel
    count (common to every pixel) and the pixel noise of the dark part
    times sqrt(count). ``complete`` is False when the aperture leaves the
    frame, so part of the light is missing.
    """

    total_gray: float
    total_err_gray: float
    n_pixels: int
    radius_px: float
    complete: bool


def aperture_sum(
    crop: Crop, radius_px: float, background_gray: float, background_err_gray: float
) -> ApertureSum:
    """Sum ``pixel - background`` over a disk of ``radius_px`` around the crop's centre.

    The pixel noise is the standard deviation of the crop outside the
    aperture (dark sensor, no source light), the background level that of
    the radial-profile fit.
    """
    pix = crop.pixels
    cx, cy = crop.center_xy
    rows = np.arange(pix.shape[0], dtype=np.float32)[:, None] - np.float32(cy)
    cols = np.arange(pix.shape[1], dtype=np.float32)[None, :] - np.float32(cx)
    dist2 = rows * rows + cols * cols
    inside = dist2 <= radius_px * radius_px
    values = pix[inside]
    finite = np.isfinite(values)
    n = int(finite.sum())
    outside = pix[(~inside) & np.isfinite(pix)]
    noise = float(np.std(outside)) if outside.size > 10 else 0.0
    total = float(np.sum(values[finite], dtype=np.float64) - n * background_gray)
    err = math.hypot(n * background_err_gray, math.sqrt(n) * noise)
    return ApertureSum(total, err, n, float(radius_px), bool(finite.all()))


@dataclass(frozen=True)
class SourceMeasurement:
    """The I_center analysis of a frame, its source's total gray and Hough radius.

    ``analysis`` is the `FrameAnalysis` without its crop and profile (they
    are large and not needed afterwards). ``total`` and ``hough_radius_px``
    are None for rejected frames, and ``hough_radius_px`` also when no
    circle was found.
    """

    analysis: FrameAnalysis
    total: ApertureSum | None
    hough_radius_px: float | None


def measure_source(frame: np.ndarray, config: FrameConfig | None = None) -> SourceMeasurement:
    """I_center, total gray and Hough radius of the source in one frame.

    The total is summed on the analysis crop, which reaches 1.6 disk radii
    and more, so the aperture of `aperture_radius_px` fits in it.
    """
    config = config or FrameConfig()
    result = analyze_frame(frame, config)
    slim = replace(result, crop=None, profile=None)
    if not result.ok or result.crop is None or result.radius_px is None:
        return SourceMeasurement(slim, None, None)
    crop = result.crop
    total = aperture_sum(
        crop,
        aperture_radius_px(result.radius_px),
        float(result.background_gray),  # type: ignore[arg-type]
        float(result.background_err_gray),  # type: ignore[arg-type]
    )
    circle = hough_radius_px(crop.pixels, result.radius_px)
    return SourceMeasurement(slim, total, circle[2] if circle is not None else None)


def gray_at(
    frame: np.ndarray, center_xy: tuple[float, float], n_pixels: int = DEFAULT_CENTER_PIXELS
) -> CenterValue:
    """Mean gray of the ``n_pixels`` pixels nearest ``center_xy`` (x, y), and its error.

    The linearity sweep compares the *same* pixels across frames, so the
    position is fixed for the whole sweep rather than found in each frame
    (the dimmest frames barely show the source).
    """
    frame = check_frame(frame)
    x, y = center_xy
    height, width = frame.shape
    if not (0 <= x <= width - 1 and 0 <= y <= height - 1):
        raise ValueError(f"center_xy {center_xy} lies outside the {width} x {height} frame")
    return center_value(frame, center_xy, n_pixels)
