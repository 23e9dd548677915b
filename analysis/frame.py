"""I_center of one frame: detection, quality checks, crop, profile, background fit."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from analysis.detect import Detection, FrameFormatError, check_frame, locate_source
from analysis.profile import (
    DEFAULT_CENTER_PIXELS,
    DEFAULT_CROP_PX,
    BackgroundFit,
    CenterValue,
    Crop,
    RadialProfile,
    center_value,
    crop_around,
    crop_half_size_px,
    fit_background,
    radial_profile,
    unclip_center,
    unclip_profile,
)


class Reason(StrEnum):
    """Why a frame was rejected. The values are the short words of the frame-set spec."""

    SATURATED = "saturated"
    TOO_DARK = "too_dark"
    NO_SOURCE = "no_source"
    OFF_EDGE = "off_edge"
    UNREADABLE = "unreadable"
    BAD_FORMAT = "bad_format"
    BAD_METADATA = "bad_metadata"


#: What each rejection means and what to do about it, for people reading reports.
REASON_HELP: dict[str, str] = {
    Reason.SATURATED: "LEM pixels above the linear range: use a shorter exposure or lower gain",
    Reason.TOO_DARK: "LEM centre below the linear range: use a longer exposure or higher gain",
    Reason.NO_SOURCE: "no LEM found: check the LEM is on and in the field of view",
    Reason.OFF_EDGE: "LEM cut by the frame edge: the module is tilted too far",
    Reason.UNREADABLE: "file missing or not a decodable image",
    Reason.BAD_FORMAT: "image is not 8- or 16-bit grayscale, or too small to hold the LEM (under 8 x 8 px)",
    Reason.BAD_METADATA: "manifest row has an invalid value",
}


#: A pixel at the frame's full scale (255 gray; a 16-bit one scaled to it, within float32's rounding).
SATURATED_GRAY = 255.0 - 1e-3


@dataclass(frozen=True)
class FrameConfig:
    """Inputs of the per-frame analysis.

    ``linear_range_gray`` is the camera's linear response range ``(low, high)``:
    a LEM centre above ``high`` is saturated, below ``low`` too dark.
    ``saturated_pixel_fraction`` is the fraction of disk pixels allowed at 255
    before the frame counts as saturated even if the centre is in range.
    ``expected_radius_px`` is the LEM's radius the geometry predicts for this
    camera (`camcal.core.frameset.Setup.disk_radius_px`): the size of the disk
    filter that finds a faint LEM (`analysis.detect.find_disk`); None tries
    several sizes.
    """

    linear_range_gray: tuple[float, float] = (5.0, 240.0)
    crop_px: int = DEFAULT_CROP_PX
    center_pixels: int = DEFAULT_CENTER_PIXELS
    saturated_pixel_fraction: float = 0.005
    edge_margin_px: float = 4.0
    expected_radius_px: float | None = None

    def __post_init__(self) -> None:
        lo, hi = self.linear_range_gray
        if not (0 <= lo < hi <= 255):
            raise ValueError(f"linear_range_gray must satisfy 0 <= low < high <= 255, got {lo, hi}")
        if self.crop_px < 20 or self.center_pixels < 1:
            raise ValueError("crop_px must be >= 20 and center_pixels >= 1")
        if self.expected_radius_px is not None and not (0 < self.expected_radius_px < 1e5):
            raise ValueError(f"expected_radius_px must be > 0 (or None), got {self.expected_radius_px}")


@dataclass(frozen=True)
class FrameAnalysis:
    """The result of analysing one frame.

    ``status`` is ``"ok"`` or ``"rejected"``; ``reason`` is a `Reason` value for
    rejected frames. ``i_center_gray`` is the background-subtracted centre gray
    (the paper's I) with its statistical error ``i_center_err_gray``.
    ``center_gray`` is the raw mean of the centre pixels, kept for rejected
    frames too: the linearity check needs the saturated ones.
    """

    status: str
    reason: str | None = None
    detail: str | None = None
    centroid_px: tuple[float, float] | None = None
    radius_px: float | None = None
    elongation: float | None = None
    center_gray: float | None = None
    center_err_gray: float | None = None
    background_gray: float | None = None
    background_err_gray: float | None = None
    i_center_gray: float | None = None
    i_center_err_gray: float | None = None
    saturated_fraction: float | None = None
    profile: RadialProfile | None = field(default=None, repr=False, compare=False)
    fit: BackgroundFit | None = None
    crop: Crop | None = field(default=None, repr=False, compare=False)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def rejected(reason: Reason | str, detail: str | None = None, **values: object) -> FrameAnalysis:
    """A rejected-frame result with its reason and a human-readable detail."""
    return FrameAnalysis(status="rejected", reason=str(reason), detail=detail, **values)  # type: ignore[arg-type]


def fit_start_radius_px(radius_px: float) -> float:
    """First band used by the background fit: outside the disk and its blurred edge."""
    return radius_px * 1.15 + 4.0


@dataclass(frozen=True)
class CropMeasurement:
    """Profile, background fit and centre value measured on one crop."""

    profile: RadialProfile
    fit: BackgroundFit
    center: CenterValue

    @property
    def i_center_gray(self) -> float:
        return self.center.mean_gray - self.fit.background_gray

    @property
    def i_center_err_gray(self) -> float:
        return math.hypot(self.center.err_gray, self.fit.background_err_gray)


def measure_crop(
    crop: Crop, radius_px: float, center_pixels: int, center: CenterValue | None = None
) -> CropMeasurement:
    """Band profile, exponential + constant background fit and centre mean of a crop.

    A sensor that clips its dark noise at zero (`analysis.censor`) has its
    band means and, with the noise of the centre pixels, its centre mean
    unclipped (the centre's matters from ~4 gray of noise on, at the bottom
    of the linear range).
    """
    r_min = fit_start_radius_px(radius_px)
    profile = unclip_profile(radial_profile(crop.pixels, crop.center_xy, zeros=crop.zeros), r_min)
    fit = fit_background(profile, r_min)
    if center is None:  # (the frame's analysis has it already, from its linear-range check)
        center = center_value(crop.pixels, crop.center_xy, center_pixels)
    if profile.unclipped is not None:
        center = unclip_center(center, profile.unclipped.sigma_gray)
    return CropMeasurement(profile, fit, center)


def to_gray(frame: np.ndarray, full_scale: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A frame as the analysis reads it: (8-bit frame to find the LEM in, gray values to measure).

    Gray values are on the 8-bit scale whatever the camera's depth: 255 gray is the frame's
    ``full_scale``, its saturation level (255 for ``uint8``; for ``uint16`` 65535 unless told,
    65520 for 12-bit data MSB-aligned as PNG keeps it). An 8-bit frame is both as it is; a deeper
    one is measured in fractional gray (its extra bits kept) and searched in its rounding.
    Raises `FrameFormatError` for anything but a 2-D ``uint8``/``uint16`` array of 8 x 8 px or more.
    """
    if isinstance(frame, np.ndarray) and frame.ndim == 2 and frame.dtype == np.uint16:
        top = 65535.0 if full_scale is None else float(full_scale)
        if not 0 < top <= 65535:
            raise FrameFormatError(f"full_scale must lie in (0, 65535] for 16-bit pixels, got {full_scale}")
        gray = frame.astype(np.float32)
        gray *= np.float32(255.0 / top)
        np.minimum(gray, np.float32(255.0), out=gray)  # (a value above the saturation level is saturated)
        return check_frame(np.rint(gray).astype(np.uint8)), gray
    if full_scale is not None and full_scale != 255:
        raise FrameFormatError(f"an 8-bit frame has a full scale of 255, not {full_scale}")
    frame = check_frame(frame)
    return frame, frame


def analyze_frame(
    frame: np.ndarray, config: FrameConfig | None = None, *, full_scale: float | None = None
) -> FrameAnalysis:
    """Measure I_center on one frame, or say why the frame cannot be used.

    ``frame`` is 8-bit, or 16-bit with its saturation level ``full_scale`` (`to_gray`): gray
    values, the linear range and the saturation check are on the 8-bit scale either way.

    1. find the LEM and its sub-pixel centroid (`locate_source`);
    2. reject it if no source stands out, or if the disk touches the frame edge;
    3. crop around the centroid (300 x 300, larger for a large disk);
    4. check the linear range on the LEM's pixels: the centre mean must lie in
       ``linear_range_gray`` and almost no disk pixel may sit at 255 (hot
       pixels outside the disk are never looked at);
    5. fit exponential + constant to the radial band profile outside the disk;
    6. I_center = centre mean - fitted constant, with errors added in quadrature.
    """
    config = config or FrameConfig()
    try:
        frame, gray = to_gray(frame, full_scale)
    except FrameFormatError as exc:  # one frame of a set, not the set: rejected, never raised
        return rejected(Reason.BAD_FORMAT, str(exc))
    det: Detection = locate_source(frame, expected_radius_px=config.expected_radius_px)
    if not det.found:
        if det.background.level_gray >= 254.5:  # not a missing LEM: light everywhere (daylight, gain)
            return rejected(
                Reason.SATURATED,
                "the whole frame is at 255: far too much light (shorter exposure, lower gain; daylight?)",
            )
        size = f"{config.expected_radius_px:.0f} px" if config.expected_radius_px else "any size"
        best = f"{det.significance:.1f} σ" if math.isfinite(det.significance) else "none measurable"
        return rejected(
            Reason.NO_SOURCE,
            f"no disk ({size}) above the noise: best {best}; brightest region "
            f"{det.peak_gray:.0f} gray over a background of "
            f"{det.background.level_gray:.1f} ± {det.background.noise_gray:.1f}",
        )
    located = {
        "centroid_px": (det.x_px, det.y_px),
        "radius_px": det.radius_px,
        "elongation": det.elongation,
    }
    height, width = frame.shape
    margin = det.radius_px + config.edge_margin_px
    outside = (
        det.x_px - margin < -0.5
        or det.y_px - margin < -0.5
        or det.x_px + margin > width - 0.5
        or det.y_px + margin > height - 0.5
    )
    if det.touches_edge or outside:
        return rejected(Reason.OFF_EDGE, "LEM disk reaches the frame border", **located)

    half = crop_half_size_px(det.radius_px, config.crop_px // 2)
    crop = crop_around(gray, det.x_px, det.y_px, half)
    center = center_value(crop.pixels, crop.center_xy, config.center_pixels)
    lo, hi = config.linear_range_gray

    disk = _disk_pixels(crop, det.radius_px)
    sat_fraction = float(np.count_nonzero(disk >= SATURATED_GRAY) / max(disk.size, 1))
    located.update(
        center_gray=center.mean_gray,
        center_err_gray=center.err_gray,
        saturated_fraction=sat_fraction,
    )
    if center.mean_gray > hi or sat_fraction > config.saturated_pixel_fraction:
        return rejected(
            Reason.SATURATED,
            f"centre {center.mean_gray:.1f} gray, {100 * sat_fraction:.1f}% of disk pixels "
            f"at 255 (linear up to {hi:g})",
            crop=crop,
            **located,
        )
    if center.mean_gray < lo:
        return rejected(
            Reason.TOO_DARK,
            f"centre {center.mean_gray:.1f} gray, below {lo:g}",
            crop=crop,
            **located,
        )

    m = measure_crop(crop, det.radius_px, config.center_pixels, center)
    return FrameAnalysis(
        status="ok",
        background_gray=m.fit.background_gray,
        background_err_gray=m.fit.background_err_gray,
        i_center_gray=m.i_center_gray,
        i_center_err_gray=m.i_center_err_gray,
        profile=m.profile,
        fit=m.fit,
        crop=crop,
        **located,  # type: ignore[arg-type]
    )


def _disk_pixels(crop: Crop, radius_px: float) -> np.ndarray:
    """Pixels of the crop inside the detected disk (radius + 1 px)."""
    cx, cy = crop.center_xy
    r = math.ceil(radius_px) + 1
    x0, y0 = max(int(cx) - r, 0), max(int(cy) - r, 0)
    window = crop.pixels[y0 : int(cy) + r + 1, x0 : int(cx) + r + 1]
    rows = np.arange(window.shape[0], dtype=np.float32)[:, None] + y0 - cy
    cols = np.arange(window.shape[1], dtype=np.float32)[None, :] + x0 - cx
    inside = rows**2 + cols**2 <= (radius_px + 1) ** 2
    values = window[inside]
    return values[np.isfinite(values)]
