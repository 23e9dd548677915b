"""Stacking repeated frames of one setting into one I_center with its error."""

from __future__ import annotations

import math
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
    cube = np.stack([c.pixels for c in crops])
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(cube)
        total = np.where(valid, cube, 0).sum(axis=0)
        count = valid.sum(axis=0)
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan).astype(np.float32)
    cx = float(np.mean([c.center_xy[0] for c in crops]))
    cy = float(np.mean([c.center_xy[1] for c in crops]))
    return Crop(mean, crops[0].origin_xy, (cx, cy))


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
    radius = float(np.median([r.radius_px for r in good]))
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
    pixels = crop.pixels[off : off + 2 * half, off : off + 2 * half]
    cx, cy = crop.center_xy
    return Crop(pixels, (crop.origin_xy[0] + off, crop.origin_xy[1] + off), (cx - off, cy - off))
