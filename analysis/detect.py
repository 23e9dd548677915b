"""Finding the LEM in a frame: background level, coarse search, sub-pixel centroid.

Conventions (see ``docs/conventions.md``): frames are 2-D ``uint8`` arrays
indexed ``[row, col]``; points are ``(x, y)`` with x to the right, y down and
the origin at the centre of the top-left pixel, so pixel ``[r, c]`` has its
centre at ``(x, y) = (c, r)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: Step of the strided subsample used by the coarse search. One pixel in 16 is
#: read, so the search costs about one read pass over the frame.
COARSE_STEP = 4
#: A faint disk is the LEM when the disk filter's response stands this many
#: standard deviations above the frame's (a 5 MP subsample holds ~1000
#: independent disk-sized cells, so noise alone reaches it about once in
#: 3000 frames; see ``bench/bench_detect.py``).
DISK_SIGNIFICANCE = 5.5
#: Disk radii (full-resolution pixels) the filter tries when the geometry gives none.
SEARCH_RADII_PX = (12.0, 24.0, 48.0, 96.0, 192.0)
_GROW_KERNEL = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))


class FrameFormatError(ValueError):
    """The array is not a 2-D 8-bit grayscale frame."""


def check_frame(frame: np.ndarray, name: str = "frame") -> np.ndarray:
    """Return ``frame`` if it is a 2-D ``uint8`` array, else raise `FrameFormatError`.

    The message names the parameter and what was received, e.g.
    ``frame must be 2-D uint8, got shape (480, 640, 3) dtype uint8``.
    """
    if not isinstance(frame, np.ndarray) or frame.ndim != 2 or frame.dtype != np.uint8:
        shape = getattr(frame, "shape", None)
        dtype = getattr(frame, "dtype", type(frame).__name__)
        raise FrameFormatError(f"{name} must be 2-D uint8, got shape {shape} dtype {dtype}")
    if frame.shape[0] < 8 or frame.shape[1] < 8:
        h, w = frame.shape
        raise FrameFormatError(f"{name} is {w} x {h} px: too small to hold the LEM (at least 8 x 8 px)")
    return frame


@dataclass(frozen=True)
class BackgroundLevel:
    """Robust level and noise of the dark part of a frame, in gray values."""

    level_gray: float
    noise_gray: float


def background_level(frame: np.ndarray) -> BackgroundLevel:
    """Estimate the dark level and its pixel noise from a strided subsample.

    Most of a T-REX frame is dark water, so the histogram's core (everything up
    to a few noise widths above the median) describes the background. The
    histogram of the subsample costs far less than a median over the frame.
    """
    return _background_from_sample(np.ascontiguousarray(frame[::COARSE_STEP, ::COARSE_STEP]))


def _background_from_sample(sample: np.ndarray) -> BackgroundLevel:
    # Every other row and column of the subsample: ~80 000 pixels of a 5 MP frame.
    hist = np.bincount(sample[::2, ::2].ravel(), minlength=256).astype(np.float64)
    cdf = np.cumsum(hist)
    total = cdf[-1]
    p16, median = np.searchsorted(cdf, (0.16 * total, 0.5 * total))
    # The lower side of the histogram only: a LEM filling a good part of the
    # frame (a near camera) lifts the upper percentiles, never the lower ones.
    spread = max(2.0 * float(median - p16), 1.0)
    hi = int(min(255, median + 3 * spread + 2))
    values = np.arange(hi + 1, dtype=np.float64)
    weights = hist[: hi + 1]
    level = float(values @ weights / weights.sum())
    noise = float(np.sqrt(((values - level) ** 2) @ weights / weights.sum()))
    # Integer gray values carry at least the quantisation noise of 1/sqrt(12).
    return BackgroundLevel(level_gray=level, noise_gray=max(noise, 0.29))


@dataclass(frozen=True)
class Detection:
    """Where the LEM is in a frame.

    Attributes
    ----------
    found
        False when no source stands significantly above the background.
    x_px, y_px
        Sub-pixel intensity-weighted centroid of the source pixels.
    radius_px
        Radius of a disk with the same area as the pixels above half maximum.
    peak_gray
        Robust peak (3 x 3 median) of the source, in gray values.
    background
        Dark level and noise used for the thresholds.
    touches_edge
        True when source pixels lie on the border of the frame: the LEM is cut.
    elongation
        ``1 - minor/major`` axis ratio of the weighted second moments; a round
        LEM gives ~0, a double image or strong motion blur gives more.
    significance
        How far the disk filter's best response stands above the frame's
        noise, in standard deviations (NaN when the peak search found a
        bright source and the filter was not needed).
    matched
        True when the LEM was found by the disk filter (a faint LEM).
    """

    found: bool
    x_px: float
    y_px: float
    radius_px: float
    peak_gray: float
    background: BackgroundLevel
    touches_edge: bool
    elongation: float
    significance: float = float("nan")
    matched: bool = False


def _not_found(
    background: BackgroundLevel, peak: float = 0.0, significance: float = float("nan")
) -> Detection:
    return Detection(False, float("nan"), float("nan"), 0.0, peak, background, False, 0.0, significance)


def _significant(peak: float, bg: BackgroundLevel, min_significance: float, min_excess_gray: float) -> bool:
    excess = peak - bg.level_gray
    return excess >= min_excess_gray and excess >= min_significance * bg.noise_gray


def _component_at(
    image: np.ndarray, seed_xy: tuple[int, int], threshold: float
) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Pixels above ``threshold`` 8-connected to ``seed_xy``: mask and bounding box.

    A flood fill visits only the component itself, so this costs nothing
    like a labelling of the whole image.
    """
    h, w = image.shape
    mask = np.zeros((h + 2, w + 2), dtype=np.uint8)
    seed_value = float(image[seed_xy[1], seed_xy[0]])
    low = max(seed_value - math.floor(threshold) - 1, 0)  # fill values > threshold
    flags = 8 | cv2.FLOODFILL_MASK_ONLY | cv2.FLOODFILL_FIXED_RANGE | (1 << 8)
    _, _, _, rect = cv2.floodFill(image, mask, seed_xy, 0, low, 255, flags)
    x, y, rw, rh = (int(v) for v in rect)
    return mask[1:-1, 1:-1].view(bool), (x, y, rw, rh)


def _search_window(
    image: np.ndarray,
    step: int,
    bg: BackgroundLevel,
    min_significance: float,
    min_excess_gray: float,
) -> tuple[int, int, int, int, float] | None:
    """Bounding box (x0, y0, x1, y1, in full-frame pixels) of the brightest source.

    ``image`` is the frame itself (``step == 1``) or its strided subsample. A
    3 x 3 median removes isolated hot pixels (one pixel wide at most) but
    keeps any source wider than a few pixels; the source is the connected
    region above half the peak height around the brightest point.
    """
    filtered = cv2.medianBlur(image, 3)
    _, peak, _, (px, py) = cv2.minMaxLoc(filtered)
    if not _significant(peak, bg, min_significance, min_excess_gray):
        return None
    threshold = bg.level_gray + 0.5 * (peak - bg.level_gray)
    _, (left, top, w, h) = _component_at(filtered, (px, py), threshold)
    margin = 2 * step + 4
    return (
        left * step - margin,
        top * step - margin,
        (left + w) * step + margin,
        (top + h) * step + margin,
        float(peak),
    )


def locate_source(
    frame: np.ndarray,
    *,
    min_significance: float = 8.0,
    min_excess_gray: float = 3.0,
    expected_radius_px: float | None = None,
    disk_significance: float = DISK_SIGNIFICANCE,
) -> Detection:
    """Find the LEM and measure its sub-pixel centroid on the full frame.

    Steps:

    1. estimate the dark level and noise (`background_level`);
    2. find the brightest region on a strided, median-filtered subsample, or,
       if nothing stands out there (a point-like source), on the full frame;
       a peak counts if it exceeds the background by both
       ``min_significance`` noise widths and ``min_excess_gray`` gray values;
    3. if no peak counts, look for a faint disk with a filter matched to
       it (`find_disk`): the mean over a disk of ``expected_radius_px`` (the
       geometry's prediction; several sizes when None) on the subsample,
       against the spread of that mean over the frame. A disk standing
       ``disk_significance`` standard deviations out is the LEM; otherwise
       there is *no source*;
    4. threshold at half the peak height in a full-resolution window around
       the region found (smoothed first for a faint disk, whose single
       pixels are mostly noise), and take the intensity-weighted centroid
       (background removed) of the connected pixels above threshold and a
       two-pixel rim.

    Isolated hot pixels do not move the result: they are removed by the median
    in the search and carry a negligible weight in the centroid.
    """
    check_frame(frame)
    height, width = frame.shape
    sample = np.ascontiguousarray(frame[::COARSE_STEP, ::COARSE_STEP])
    bg = _background_from_sample(sample)
    box = _search_window(sample, COARSE_STEP, bg, min_significance, min_excess_gray)
    if box is None:
        box = _search_window(frame, 1, bg, min_significance, min_excess_gray)
    if box is None:
        disk = find_disk(sample, COARSE_STEP, expected_radius_px, bg)
        if disk.significance < disk_significance:
            return _not_found(bg, float(sample.max()), disk.significance)
        return _faint_disk(frame, bg, disk)
    bx0, by0, bx1, by1, peak = box
    x0, y0 = max(bx0, 0), max(by0, 0)
    x1, y1 = min(bx1, width), min(by1, height)
    window = frame[y0:y1, x0:x1]
    filtered = cv2.medianBlur(window, 3)
    _, fine_peak, _, (lx, ly) = cv2.minMaxLoc(filtered)
    peak = max(peak, float(fine_peak))
    threshold = bg.level_gray + 0.5 * (peak - bg.level_gray)
    component, _ = _component_at(filtered, (lx, ly), threshold)
    if expected_radius_px:
        peak, component = _past_specks(filtered, bg, peak, component, expected_radius_px)
    # Weigh the component grown by two pixels: the whole antialiased and blurred
    # edge counts, on every side alike, so thresholding does not bias the centroid.
    grown = cv2.dilate(component.view(np.uint8), _GROW_KERNEL).view(bool)
    weights = np.where(grown, window.astype(np.float32) - np.float32(bg.level_gray), 0)
    np.maximum(weights, 0, out=weights)
    m = cv2.moments(weights)
    if m["m00"] <= 0:
        return _not_found(bg, peak)
    x_local, y_local = m["m10"] / m["m00"], m["m01"] / m["m00"]
    mu20, mu02, mu11 = m["mu20"] / m["m00"], m["mu02"] / m["m00"], m["mu11"] / m["m00"]
    spread = np.sqrt(max((mu20 - mu02) ** 2 + 4 * mu11**2, 0.0))
    major, minor = 0.5 * (mu20 + mu02 + spread), 0.5 * (mu20 + mu02 - spread)
    elongation = 1.0 - float(np.sqrt(max(minor, 0.0) / major)) if major > 0 else 0.0
    area = int(component.sum())
    touches = bool(
        (x0 == 0 and component[:, 0].any())
        or (y0 == 0 and component[0, :].any())
        or (x1 == width and component[:, -1].any())
        or (y1 == height and component[-1, :].any())
    )
    return Detection(
        found=True,
        x_px=float(x0 + x_local),
        y_px=float(y0 + y_local),
        radius_px=float(np.sqrt(area / np.pi)),
        peak_gray=peak,
        background=bg,
        touches_edge=touches,
        elongation=elongation,
    )


#: A component this much smaller than the disk the geometry predicts is a speck on or beside it.
SPECK_RADIUS_FRACTION = 0.5
#: Specks taken out before the LEM's own peak is found.
MAX_SPECKS = 4


def _past_specks(
    filtered: np.ndarray, bg: BackgroundLevel, peak: float, component: np.ndarray, expected_radius_px: float
) -> tuple[float, np.ndarray]:
    """The LEM's peak and pixels when a speck brighter than the LEM held the window's maximum.

    A bioluminescence flash on or beside a faint disk is brighter than it:
    thresholded at half *its* height, only the speck was "the source" (a 3 x
    3 speck of +120 gray on a 40-gray disk of radius 45 px gave radius 1.3 px
    and a background fitted inside the disk). A component far smaller than
    the predicted disk is taken out of the search (set to the dark level)
    and the next peak tried, up to `MAX_SPECKS` times; if none is the disk's
    size, the first component stands.
    """

    def disk_sized(c: np.ndarray) -> bool:
        return math.sqrt(c.sum() / math.pi) >= SPECK_RADIUS_FRACTION * expected_radius_px

    if disk_sized(component):
        return peak, component
    search = filtered.copy()
    speck = component
    for _ in range(MAX_SPECKS):
        grown = cv2.dilate(speck.view(np.uint8), _GROW_KERNEL).view(bool)
        search[grown] = np.uint8(min(max(round(bg.level_gray), 0), 255))
        _, next_peak, _, (lx, ly) = cv2.minMaxLoc(search)
        if next_peak <= bg.level_gray:
            break
        speck, _ = _component_at(search, (lx, ly), bg.level_gray + 0.5 * (next_peak - bg.level_gray))
        if disk_sized(speck):
            return float(next_peak), speck
    return peak, component


@dataclass(frozen=True)
class DiskResponse:
    """The disk filter's best response: where, how significant, at which radius."""

    x_px: float
    y_px: float
    radius_px: float
    significance: float


def find_disk(sample: np.ndarray, step: int, radius_px: float | None, bg: BackgroundLevel) -> DiskResponse:
    """The most significant disk in a strided subsample of a frame.

    The subsample (every ``step``-th pixel) is clipped ten noise widths
    above the dark level (a hot pixel or a speck then weighs no more than a
    few noisy pixels) and averaged over a square of the disk's area (a box
    filter: the matched filter of a uniform disk, up to its corners). The
    noise of that average is measured on the frame itself: the spread of
    the filtered image's lower half (below its median), where the LEM and
    its halo, which only raise values, cannot reach; it is never taken
    below what the frame's pixel noise (``bg``) would give as white noise. Several
    radii are tried when ``radius_px`` is None. Coordinates are
    full-resolution pixels.
    """
    # Above any disk the peak search let through (< 8 noise widths or 3 gray), below a hot pixel.
    top_gray = bg.level_gray + max(10.0 * bg.noise_gray, 4.0)
    clipped = np.minimum(sample, np.float32(top_gray), dtype=np.float32)
    binned: np.ndarray | None = None
    best = DiskResponse(float("nan"), float("nan"), 0.0, -math.inf)
    radii = (radius_px,) if radius_px else SEARCH_RADII_PX
    for r in radii:
        # A large disk is filtered on 2 x 2 means of the subsample: the same pixels, a quarter of the work.
        k = 2 if math.sqrt(math.pi) * r / step >= 16 else 1
        if k == 2 and binned is None:
            half = (clipped.shape[1] // 2, clipped.shape[0] // 2)
            binned = cv2.resize(clipped, half, interpolation=cv2.INTER_AREA)
        img = binned if k == 2 and binned is not None else clipped
        h, w = img.shape
        side = max(round(math.sqrt(math.pi) * r / (step * k)), 1)
        if side >= min(h, w):
            continue
        mean = cv2.boxFilter(img, -1, (side, side), borderType=cv2.BORDER_REFLECT)
        # Only where the whole box lies inside the frame: the borders repeat pixels.
        m = side // 2
        inner = mean[m : h - (side - 1 - m), m : w - (side - 1 - m)]
        if inner.size < 16:
            continue
        thin = max(min(side // 2, int(math.sqrt(inner.size / 400))), 1)
        p16, med = np.percentile(inner[::thin, ::thin], (15.87, 50.0))
        # The measured spread catches structure (gradients, a halo from outside the view); white
        # noise of the frame's own pixel noise is the least it can be (few samples can say less).
        spread = max(float(med - p16), bg.noise_gray / (side * k), 0.29 / (side * k))
        _, top, _, (ix, iy) = cv2.minMaxLoc(inner)
        sig = (float(top) - float(med)) / spread
        if sig > best.significance:
            x, y = ((ix + m) * k + (k - 1) / 2) * step, ((iy + m) * k + (k - 1) / 2) * step
            best = DiskResponse(float(x), float(y), float(r), sig)
    return best


def _faint_disk(frame: np.ndarray, bg: BackgroundLevel, disk: DiskResponse) -> Detection:
    """Centroid and size of a faint disk found by `find_disk`, on a smoothed full-resolution window."""
    height, width = frame.shape
    reach = round(2.0 * disk.radius_px + 3 * COARSE_STEP + 4)
    cx, cy = round(disk.x_px), round(disk.y_px)
    x0, y0 = max(cx - reach, 0), max(cy - reach, 0)
    x1, y1 = min(cx + reach + 1, width), min(cy + reach + 1, height)
    window = frame[y0:y1, x0:x1].astype(np.float32)
    k = max(3, 2 * round(disk.radius_px / 8.0) + 1)
    smooth = cv2.blur(window, (k, k), borderType=cv2.BORDER_REFLECT)
    _, peak, _, (lx, ly) = cv2.minMaxLoc(smooth)
    threshold = bg.level_gray + 0.5 * (float(peak) - bg.level_gray)
    component = (smooth > threshold).astype(np.uint8)
    _, labels = cv2.connectedComponents(component, connectivity=8)
    mask = labels == labels[ly, lx]
    grown = cv2.dilate(mask.view(np.uint8), _GROW_KERNEL).view(bool)
    weights = np.where(grown, smooth - np.float32(bg.level_gray), 0)
    np.maximum(weights, 0, out=weights)
    m = cv2.moments(weights)
    if m["m00"] <= 0:
        return _not_found(bg, float(peak), disk.significance)
    x_local, y_local = m["m10"] / m["m00"], m["m01"] / m["m00"]
    mu20, mu02, mu11 = m["mu20"] / m["m00"], m["mu02"] / m["m00"], m["mu11"] / m["m00"]
    spread = np.sqrt(max((mu20 - mu02) ** 2 + 4 * mu11**2, 0.0))
    major, minor = 0.5 * (mu20 + mu02 + spread), 0.5 * (mu20 + mu02 - spread)
    elongation = 1.0 - float(np.sqrt(max(minor, 0.0) / major)) if major > 0 else 0.0
    touches = bool(
        (x0 == 0 and mask[:, 0].any())
        or (y0 == 0 and mask[0, :].any())
        or (x1 == width and mask[:, -1].any())
        or (y1 == height and mask[-1, :].any())
    )
    return Detection(
        found=True,
        x_px=float(x0 + x_local),
        y_px=float(y0 + y_local),
        radius_px=float(np.sqrt(mask.sum() / np.pi)),
        peak_gray=float(peak),
        background=bg,
        touches_edge=touches,
        elongation=elongation,
        significance=disk.significance,
        matched=True,
    )
