"""The crop around the LEM, its radial band profile, the background fit and I_center."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from analysis.censor import Unclipping, inversion_slope, unclip_bands, unclipped_mean

#: The crop of the T-REX analysis: 300 x 300 pixels around the centroid.
DEFAULT_CROP_PX = 300
#: Pixels averaged at the centroid for I_center (the paper uses ~100).
DEFAULT_CENTER_PIXELS = 100


#: Centre pixels this many robust standard deviations from the centre's median are left out.
CENTER_CLIP_SIGMAS = 5.0
#: The crop reaches at least this many disk radii from the centroid (see `crop_half_size_px`).
CROP_REACH_RADII = 2.5


def crop_half_size_px(radius_px: float, minimum_px: int = DEFAULT_CROP_PX // 2) -> int:
    """Half-size of the crop: 150 px, or more when the LEM would fill too much of that.

    The band profile needs room outside the disk for the background fit,
    the same room in units of the disk for every camera: the crop reaches
    at least `CROP_REACH_RADII` disk radii plus a margin. With the paper's
    fixed 300 x 300 crop the near T-REX camera (disk radius ~87 px) would
    see only 1.7 radii, where its halo has not flattened yet: the fit's
    constant then takes in halo light, and λ_att came out ~0.7 % high on
    simulated frames (``bench/repeatability.py``; ~0.2 % with 2.5 radii).
    For T-REX: 300 x 300 for the far camera (~45 px), 456 x 456 for the
    near one.
    """
    return max(int(minimum_px), math.ceil(CROP_REACH_RADII * radius_px + 10))


@dataclass(frozen=True)
class Crop:
    """A square cut of the frame centred on the rounded centroid.

    ``pixels`` is float32 with NaN where the crop reaches outside the frame.
    ``origin_xy`` is the frame position of the crop's pixel ``[0, 0]``, and
    ``center_xy`` the sub-pixel centroid in crop coordinates. ``zeros`` is,
    per pixel, the share of the frames in which it read 0 (a stack's crop
    averages its frames'), or None when none did: where many do, the
    camera's black level sits at zero and the dark bands' means are clipped
    (`analysis.censor`).
    """

    pixels: np.ndarray
    origin_xy: tuple[int, int]
    center_xy: tuple[float, float]
    zeros: np.ndarray | None = None

    @property
    def half_size_px(self) -> int:
        return self.pixels.shape[0] // 2


def crop_around(frame: np.ndarray, x_px: float, y_px: float, half_size_px: int) -> Crop:
    """Cut a ``2*half`` square around ``(x_px, y_px)``; outside the frame is NaN.

    Crops of repeated frames centred on their own centroids are aligned to
    within half a pixel, which is what makes stacking them meaningful.
    """
    size = 2 * half_size_px
    cx, cy = round(x_px), round(y_px)
    x0, y0 = cx - half_size_px, cy - half_size_px
    height, width = frame.shape
    out = np.full((size, size), np.nan, dtype=np.float32)
    fx0, fy0 = max(x0, 0), max(y0, 0)
    fx1, fy1 = min(x0 + size, width), min(y0 + size, height)
    zeros = None
    if fx1 > fx0 and fy1 > fy0:
        part = frame[fy0:fy1, fx0:fx1]
        out[fy0 - y0 : fy1 - y0, fx0 - x0 : fx1 - x0] = part
        if part.min() == 0:  # (a minimum is several times cheaper than a comparison of every pixel)
            zeros = np.zeros((size, size), dtype=np.float32)
            zeros[fy0 - y0 : fy1 - y0, fx0 - x0 : fx1 - x0] = part == 0
    return Crop(out, (x0, y0), (x_px - x0, y_px - y0), zeros)


@dataclass(frozen=True)
class RadialProfile:
    """Mean gray per one-pixel radius band around the centroid.

    Band ``i`` holds the pixels whose centre lies at a distance in
    ``[i, i + 1)`` pixels from the centroid. ``sem_gray`` is the standard error
    of each band mean (pixel scatter over sqrt(count)). ``zero_fraction`` is
    each band's share of pixels that read 0 (None: none did); ``unclipped``
    says how `unclip_profile` undid a clipping at zero, if it did.
    """

    radius_px: np.ndarray
    mean_gray: np.ndarray
    sem_gray: np.ndarray
    count: np.ndarray
    zero_fraction: np.ndarray | None = None
    unclipped: Unclipping | None = None


def _distance_map(shape: tuple[int, int], center_xy: tuple[float, float]) -> np.ndarray:
    rows = np.arange(shape[0], dtype=np.float32) - np.float32(center_xy[1])
    cols = np.arange(shape[1], dtype=np.float32) - np.float32(center_xy[0])
    return np.sqrt(rows[:, None] ** 2 + cols[None, :] ** 2)


def radial_profile(
    pixels: np.ndarray,
    center_xy: tuple[float, float],
    max_radius_px: int | None = None,
    zeros: np.ndarray | None = None,
) -> RadialProfile:
    """Mean gray of each one-pixel band around ``center_xy`` (NaN pixels skipped).

    Averaging a whole band beats single pixels near zero, where integer gray
    values are coarse; the band means trace the scattered-light halo smoothly.
    ``zeros`` (a `Crop`'s) gives each band's share of pixels that read 0.
    """
    dist = _distance_map(pixels.shape, center_xy)
    if max_radius_px is None:
        max_radius_px = min(pixels.shape) // 2
    # Every pixel in one pass, without copying the selection out: pixels beyond the last band
    # and outside the frame (NaN) go to one extra bin, dropped.
    # intp: np.bincount takes no other index type without converting a copy first (2.4x the time)
    idx = np.minimum(dist, np.float32(max_radius_px)).astype(np.intp).ravel()
    values = pixels.ravel().astype(np.float64)
    finite = np.isfinite(values)
    if not finite.all():
        idx[~finite] = max_radius_px
        values[~finite] = 0.0
    n = max_radius_px + 1
    count = np.bincount(idx, minlength=n)[:max_radius_px]
    total = np.bincount(idx, weights=values, minlength=n)[:max_radius_px]
    values *= values  # (a copy of the pixels already: squared in place)
    total2 = np.bincount(idx, weights=values, minlength=n)[:max_radius_px]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / count
        var = np.maximum(total2 / count - mean**2, 0.0)
        sem = np.sqrt(var / np.maximum(count - 1, 1))
        zero_fraction = None
        if zeros is not None:  # (pixels outside the frame went to the dropped bin above)
            zero_fraction = np.bincount(idx, weights=zeros.ravel(), minlength=n)[:max_radius_px] / count
    return RadialProfile(
        radius_px=np.arange(max_radius_px, dtype=np.float64) + 0.5,
        mean_gray=mean,
        sem_gray=sem,
        count=count,
        zero_fraction=zero_fraction,
    )


def unclip_profile(profile: RadialProfile, r_min_px: float) -> RadialProfile:
    """The profile with a clipping at zero undone (`analysis.censor`); as it is if nothing was clipped.

    The bands from ``r_min_px`` outward (outside the disk, where the noise
    is the sensor's) measure the pixel noise; every band's mean is then
    corrected with it.
    """
    if profile.zero_fraction is None:
        return profile
    done = unclip_bands(
        profile.mean_gray,
        profile.sem_gray,
        profile.count,
        profile.zero_fraction,
        profile.radius_px >= r_min_px,
    )
    if done is None:
        return profile
    mean, sem, how = done
    return replace(profile, mean_gray=mean, sem_gray=sem, unclipped=how)


@dataclass(frozen=True)
class BackgroundFit:
    """``mean_gray(r) = amplitude_gray * exp(-r / scale_px) + background_gray``.

    Fitted to the bands from ``r_min_px`` outward. ``background_gray`` is the
    constant: the sensor's dark level plus ambient light, under the halo.
    ``converged`` is False when the fit failed and the background is the mean
    of the outermost bands instead.
    """

    amplitude_gray: float
    scale_px: float
    background_gray: float
    background_err_gray: float
    r_min_px: float
    chi2_ndof: float
    converged: bool

    def model(self, radius_px: np.ndarray) -> np.ndarray:
        return self.amplitude_gray * np.exp(-radius_px / self.scale_px) + self.background_gray


def _linear_solve(e: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Weighted least squares of ``y = A e + C`` for each row of ``e``, with A >= 0.

    For a fixed decay scale the model is linear in A and C: a 2 x 2 solve.
    Where the unconstrained A comes out negative, the constrained optimum is
    A = 0 and C = the weighted mean.
    """
    sw, swy = w.sum(), (w * y).sum()
    se, see = (e * w).sum(axis=-1), (e * e * w).sum(axis=-1)
    sey = (e * w * y).sum(axis=-1)
    det = see * sw - se * se
    with np.errstate(invalid="ignore", divide="ignore"):
        amp = (sey * sw - se * swy) / det
        const = (see * swy - se * sey) / det
    flat = ~(np.isfinite(amp) & (amp > 0))
    amp = np.where(flat, 0.0, amp)
    const = np.where(flat, swy / sw, const)
    chi2 = (((y - amp[..., None] * e - const[..., None]) ** 2) * w).sum(axis=-1)
    return amp, const, chi2


def fit_background(profile: RadialProfile, r_min_px: float) -> BackgroundFit:
    """Fit exponential + constant to the bands outside the disk.

    Scattered light falls off steeply away from the LEM and the CMOS floor
    is flat, so the constant of the fit is the background to subtract from the
    centre pixels. Bands are weighted by their standard errors (floored at
    the quantisation step over the band size, so that perfectly flat integer
    bands do not get infinite weight).

    The model is linear in amplitude and constant for a fixed decay scale, so
    the fit profiles them out: a grid over the scale finds the best region
    and a finer grid with a parabolic step refines it. The amplitude is kept
    >= 0 (scattered light adds, never removes) and the scale within the
    fitted span: a longer scale would make the exponential indistinguishable
    from the constant and the constant meaningless. Errors come from the
    Jacobian of the full three-parameter model at the minimum.
    """
    sel = (profile.radius_px >= r_min_px) & (profile.count > 0) & np.isfinite(profile.mean_gray)
    r = profile.radius_px[sel]
    y = profile.mean_gray[sel]
    floor = 0.29 / np.sqrt(np.maximum(profile.count[sel], 1))
    sigma = np.maximum(profile.sem_gray[sel], floor)
    if len(y) == 0:
        return BackgroundFit(0.0, 1.0, float("nan"), float("nan"), r_min_px, float("nan"), False)
    w = 1.0 / sigma**2
    if len(r) < 6:
        n_tail = len(y)
        err = float(np.sqrt(np.sum(sigma**2)) / n_tail)
        return BackgroundFit(0.0, 1.0, float(np.mean(y)), err, r_min_px, float("nan"), False)
    x = r - r[0]
    span = max(float(x[-1]), 2.0)
    log_lo, log_hi = math.log(0.5), math.log(span)

    def chi2_at(log_scales: np.ndarray) -> np.ndarray:
        return _linear_solve(np.exp(-x[None, :] / np.exp(log_scales)[:, None]), y, w)[2]

    grid = np.linspace(log_lo, log_hi, 32)
    chi2_grid = chi2_at(grid)
    k = int(np.argmin(chi2_grid))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)]
    # Refine: a fine grid across the two coarse cells around the minimum (one vectorised solve),
    # then the vertex of the parabola through the best fine point and its neighbours.
    fine = np.linspace(lo, hi, 33)
    chi2_fine = chi2_at(fine)
    j = int(np.argmin(chi2_fine))
    log_scale = float(fine[j])
    if 0 < j < len(fine) - 1:
        c_lo, c_mid, c_hi = chi2_fine[j - 1], chi2_fine[j], chi2_fine[j + 1]
        curvature = c_lo - 2.0 * c_mid + c_hi
        if curvature > 0:
            step = float(fine[1] - fine[0])
            vertex = log_scale + 0.5 * step * float(c_lo - c_hi) / float(curvature)
            if float(chi2_at(np.array([vertex]))[0]) <= c_mid:
                log_scale = vertex
    scale = math.exp(log_scale)
    e = np.exp(-x / scale)
    amp_a, const_a, chi2_a = _linear_solve(e, y, w)
    amp, const, chi2 = float(amp_a), float(const_a), float(chi2_a)
    if amp > 0:
        jac = np.column_stack([e, amp * x * e / (scale * scale), np.ones_like(x)])
    else:
        jac = np.ones((len(x), 1))
    cov = np.linalg.pinv(jac.T @ (jac * w[:, None]))
    err = float(math.sqrt(max(cov[-1, -1], 0.0)))
    ndof = max(len(r) - jac.shape[1], 1)
    chi2_ndof = chi2 / ndof
    # A poor fit (chi2/ndof > 1) means the model misses structure: widen the error.
    err *= math.sqrt(max(chi2_ndof, 1.0))
    amplitude = amp * math.exp(r[0] / scale)  # referred to r = 0
    return BackgroundFit(amplitude, scale, const, err, r_min_px, chi2_ndof, True)


@dataclass(frozen=True)
class CenterValue:
    """Mean gray of the pixels nearest the centroid and its standard error."""

    mean_gray: float
    err_gray: float
    n_pixels: int


def center_value(
    pixels: np.ndarray, center_xy: tuple[float, float], n_pixels: int = DEFAULT_CENTER_PIXELS
) -> CenterValue:
    """Mean of the ``n_pixels`` pixels whose centres lie nearest the centroid.

    These pixels see the LEM's centre, so they carry the direct, unscattered
    light; their scatter over sqrt(n) is the statistical error of the mean.
    A pixel further than `CENTER_CLIP_SIGMAS` robust standard deviations
    (1.4826 × the median absolute deviation, at least half a gray value)
    from their median is left out: a bioluminescence speck or a hot pixel
    on the LEM's centre is not its light (a 3 × 3 speck of +120 gray made a
    40-gray centre read 52 ± 3.8). Gaussian noise loses one pixel in 1.7
    million to it.
    """
    reach = math.ceil(math.sqrt(n_pixels / math.pi)) + 2
    cx, cy = center_xy
    x0, y0 = max(round(cx) - reach, 0), max(round(cy) - reach, 0)
    x1 = min(round(cx) + reach + 1, pixels.shape[1])
    y1 = min(round(cy) + reach + 1, pixels.shape[0])
    window = pixels[y0:y1, x0:x1]
    dist = _distance_map(window.shape, (cx - x0, cy - y0)).ravel()
    values = window.ravel()
    ok = np.isfinite(values)
    dist, values = dist[ok], values[ok]
    if values.size == 0:
        return CenterValue(float("nan"), float("nan"), 0)
    k = min(n_pixels, values.size)
    nearest = values[np.argsort(dist, kind="stable")[:k]].astype(np.float64)
    if k >= 8:
        median = _median(np.sort(nearest))
        deviation = np.abs(nearest - median)
        spread = max(1.4826 * _median(np.sort(deviation)), 0.5)
        keep = deviation <= CENTER_CLIP_SIGMAS * spread
        if not keep.all():
            nearest = nearest[keep]
            k = nearest.size
    err = float(nearest.std(ddof=1) / math.sqrt(k)) if k > 1 else float("nan")
    # Integer gray values: never claim better than quantisation allows.
    err = max(err, 0.29 / math.sqrt(k))
    return CenterValue(float(nearest.mean()), err, k)


def _median(ordered: np.ndarray) -> float:
    """The median of sorted values (np.median's checks cost more than its work on a hundred)."""
    k = ordered.size
    return 0.5 * float(ordered[(k - 1) // 2] + ordered[k // 2])


def unclip_center(center: CenterValue, read_noise_gray: float) -> CenterValue:
    """The centre mean of a sensor that clips at zero, unclipped with the centre pixels' own noise.

    That noise is the larger of the dark bands' (``read_noise_gray``) and
    the centre pixels' scatter (the LEM's shot noise adds to it).
    """
    sigma = max(read_noise_gray, center.err_gray * math.sqrt(max(center.n_pixels, 1)))
    mean = float(unclipped_mean(np.array([center.mean_gray]), sigma)[0])
    return CenterValue(mean, center.err_gray / float(inversion_slope(mean, sigma)), center.n_pixels)
