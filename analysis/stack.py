"""Stacking repeated frames of one setting into one I_center with its error."""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from analysis.frame import CropMeasurement, FrameAnalysis, measure_crop
from analysis.profile import DEFAULT_CENTER_PIXELS, Crop


@dataclass(frozen=True)
class StackResult:
    """I_center of a stack of repeats at one setting.

    ``i_center_gray`` is measured on the mean of the aligned crops (the
    stacked image, as in the paper). Its error ``i_center_err_gray`` is the
    larger of the frame-to-frame scatter of the single-frame values over
    sqrt(n) and the single-frame errors propagated: the scatter catches what
    the per-frame errors cannot (flicker, pointing), the propagation protects
    small stacks from a lucky small scatter. ``center_xy`` is the sub-pixel
    centre of the LEM in ``stacked_pixels`` (the mean of the frames' centres),
    around which the profile's bands were drawn.
    """

    i_center_gray: float
    i_center_err_gray: float
    n_frames: int
    background_gray: float
    radius_px: float
    frame_values_gray: tuple[float, ...]
    measurement: CropMeasurement | None = field(default=None, repr=False, compare=False)
    stacked_pixels: np.ndarray | None = field(default=None, repr=False, compare=False)
    center_xy: tuple[float, float] | None = None


def stack_crops(crops: Sequence[Crop]) -> Crop:
    """Mean of equally sized crops, each centred on its own centroid.

    Pixels outside the frame (NaN) are left out of the mean. The result's
    centre is the mean of the sub-pixel centres.
    """
    if not crops:
        raise ValueError("stack_crops needs at least one crop")
    shape = crops[0].pixels.shape
    if any(c.pixels.shape != shape for c in crops):
        raise ValueError("crops of a stack must share one shape; crop them with one half-size")
    # The plain mean first: a pixel outside the frame in any crop makes it NaN there, and only
    # those pixels (a LEM near the frame's edge; usually none) need the mean over the finite values.
    mean = np.array(crops[0].pixels, dtype=np.float32)
    for c in crops[1:]:
        mean += c.pixels
    mean /= np.float32(len(crops))
    holes = np.flatnonzero(np.isnan(mean))
    if holes.size:
        values = np.stack([c.pixels.ravel()[holes] for c in crops])
        valid = np.isfinite(values)
        count = valid.sum(axis=0)
        total = np.where(valid, values, 0).sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean.ravel()[holes] = np.where(count > 0, total / count, np.nan)
    cx = float(np.mean([c.center_xy[0] for c in crops]))
    cy = float(np.mean([c.center_xy[1] for c in crops]))
    # The share of the frames in which each pixel read 0 (a frame without zeros adds none).
    zeros = None
    if any(c.zeros is not None for c in crops):
        zeros = np.zeros(shape, dtype=np.float32)
        for c in crops:
            if c.zeros is not None:
                zeros += c.zeros
        zeros /= np.float32(len(crops))
    return Crop(mean, crops[0].origin_xy, (cx, cy), zeros)


def stack_frames(results: Sequence[FrameAnalysis], center_pixels: int = DEFAULT_CENTER_PIXELS) -> StackResult:
    """Stack the accepted repeats of one setting.

    Only frames with status ``ok`` are used. Crops of differing size (a LEM
    whose measured radius crossed the crop rule) are re-centred on the
    smallest common size before averaging.
    """
    good = [r for r in results if r.ok and r.crop is not None and r.i_center_gray is not None]
    if not good:
        raise ValueError("no accepted frame to stack")
    half = min(r.crop.half_size_px for r in good)  # type: ignore[union-attr]
    crops = [_recentre(r.crop, half) for r in good]  # type: ignore[arg-type]
    stacked = stack_crops(crops)
    # statistics, not np.median: that would import numpy.ma (35 ms) for a handful of numbers
    radius = statistics.median(float(r.radius_px) for r in good if r.radius_px is not None)
    m = measure_crop(stacked, radius, center_pixels)
    values = np.array([r.i_center_gray for r in good], dtype=np.float64)
    errors = np.array([r.i_center_err_gray for r in good], dtype=np.float64)
    n = len(values)
    propagated = float(math.sqrt(np.sum(errors**2)) / n)
    scatter = float(values.std(ddof=1) / math.sqrt(n)) if n >= 3 else 0.0
    return StackResult(
        i_center_gray=m.i_center_gray,
        i_center_err_gray=max(scatter, propagated),
        n_frames=n,
        background_gray=m.fit.background_gray,
        radius_px=radius,
        frame_values_gray=tuple(float(v) for v in values),
        measurement=m,
        stacked_pixels=stacked.pixels,
        center_xy=stacked.center_xy,
    )


def _recentre(crop: Crop, half: int) -> Crop:
    """The central ``2*half`` square of a larger crop."""
    if crop.half_size_px == half:
        return crop
    off = crop.half_size_px - half
    window = (slice(off, off + 2 * half), slice(off, off + 2 * half))
    zeros = crop.zeros[window] if crop.zeros is not None else None
    cx, cy = crop.center_xy
    origin = (crop.origin_xy[0] + off, crop.origin_xy[1] + off)
    return Crop(crop.pixels[window], origin, (cx - off, cy - off), zeros)
