"""The direct light of the LEM: its disk in the image, blurred and averaged like the data.

The simulator and the fit draw the disk over a radius ``f a / sqrt(L² - a²)``
pixels, antialiased by a one-pixel linear ramp at the edge, then blurred by a
Gaussian PSF. Its radiance is ``B exp(-s/λ_att)`` with ``s`` the path in water
from the camera to the sphere's surface along each pixel's ray
(`surface_path_m`): ``L - a`` at the centre, ``sqrt(L² - a²)`` at the limb.
Writing ``exp(-L/λ_att)`` instead (the distance to the LEM's centre) makes the
disk too faint by ``a/λ_att`` against the halo, whose paths start at the
surface. The I_center method takes the near/far ratio of the centre pixels,
in which the ``a`` cancels. A profile band is the mean over the pixels whose
centres lie in it, so the model is evaluated at exactly those pixel centres
(`BandPixels`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chndtr, roots_legendre

#: Gauss-Legendre nodes over the one-pixel edge ramp, by the PSF's width: the fewest whose
#: blurred disk stays within 3·10⁻⁷ of a 48-node one for radii of 4-44 px (a narrow PSF leaves a
#: sharp step inside the ramp and needs many; 8 nodes at σ = 0.1 px were off by 3·10⁻⁴).
_RAMP_NODES = ((0.7, 4), (0.5, 5), (0.3, 6), (0.2, 8), (0.0, 48))


def disk_radius_px(distance_m: float, lem_radius_m: float, focal_px: float) -> float:
    """Radius of the LEM's image: f·a / sqrt(L² - a²)."""
    if not distance_m > lem_radius_m:
        raise ValueError(f"distance_m {distance_m} must exceed lem_radius_m {lem_radius_m}")
    return focal_px * lem_radius_m / math.sqrt(distance_m * distance_m - lem_radius_m * lem_radius_m)


def surface_path_excess_m(
    rho_px: np.ndarray | float, distance_m: float, lem_radius_m: float, focal_px: float
) -> np.ndarray:
    """How much longer the ray through a pixel ``rho_px`` from the disk's centre travels to the sphere.

    The ray at angle ψ (tan ψ = ρ/f) from the line to the centre meets the
    sphere of radius a at distance L after ``s = L cos ψ - sqrt(a² - L² sin² ψ)``;
    this returns ``δ = s - (L - a)`` (0 at the centre, about a at the limb),
    written without cancellation as ``a - 2 L sin²(ψ/2) - sqrt(a² - L² sin² ψ)``.
    Rays that miss the sphere (the antialiasing ramp's outer half) take the
    limb's value.
    """
    psi = np.arctan(np.asarray(rho_px, dtype=np.float64) / focal_px)
    big_l, a = float(distance_m), float(lem_radius_m)
    root = np.sqrt(np.clip(a * a - (big_l * np.sin(psi)) ** 2, 0.0, None))
    limb = math.sqrt(big_l * big_l - a * a) - (big_l - a)
    inside = big_l * np.sin(psi) < a
    return np.where(inside, a - 2.0 * big_l * np.sin(0.5 * psi) ** 2 - root, limb)


def surface_path_m(
    rho_px: np.ndarray | float, distance_m: float, lem_radius_m: float, focal_px: float
) -> np.ndarray:
    """Path in water from the camera to the LEM's surface along the ray through ``rho_px``."""
    return (distance_m - lem_radius_m) + surface_path_excess_m(rho_px, distance_m, lem_radius_m, focal_px)


def blurred_disk(rho_px: np.ndarray, radius_px: float, sigma_px: float) -> np.ndarray:
    """The unit disk with a one-pixel edge ramp, blurred by a 2-D Gaussian, at distances ``rho_px``.

    The ramp clip(R - ρ + 1/2, 0, 1) is the mean of sharp disks with radii
    uniform in [R - 1/2, R + 1/2]. A sharp disk of radius R' blurred by a
    Gaussian of width σ has, at distance ρ from its centre, the value
    P(|X| < R') for X ~ N((ρ, 0), σ²): a noncentral χ² with 2 degrees of
    freedom, ``chndtr((R'/σ)², 2, (ρ/σ)²)``. The ramp is integrated by
    Gauss-Legendre, with as many nodes as the PSF's width needs (`_RAMP_NODES`).
    For σ below 0.05 px the ramp itself is returned.
    """
    rho = np.asarray(rho_px, dtype=np.float64)
    if sigma_px < 0.05:
        return np.clip(radius_px - rho + 0.5, 0.0, 1.0)
    nodes, weights = roots_legendre(next(n for width, n in _RAMP_NODES if sigma_px >= width))
    out = np.zeros_like(rho)
    nc = (rho / sigma_px) ** 2
    for x, w in zip(nodes, weights, strict=True):
        r = radius_px + 0.5 * x
        out += 0.5 * w * chndtr((r / sigma_px) ** 2, 2, nc)
    return out


@dataclass(frozen=True)
class BandPixels:
    """The pixel centres of each one-pixel band of a crop, for averaging a model as the profile does.

    Built from the crop's shape and the sub-pixel centre its profile was drawn
    around (`analysis.profile.radial_profile`'s conventions: band ``i`` holds
    pixels at distances in ``[i, i + 1)``). Pixels outside the frame (NaN in
    the crop) are left out, as the profile leaves them out.
    """

    distance_px: np.ndarray = field(repr=False)
    band: np.ndarray = field(repr=False)
    count: np.ndarray = field(repr=False)
    flat_index: np.ndarray = field(repr=False)

    @classmethod
    def from_crop(
        cls,
        shape: tuple[int, int],
        center_xy: tuple[float, float],
        n_bands: int,
        valid: np.ndarray | None = None,
    ) -> BandPixels:
        rows = np.arange(shape[0], dtype=np.float32) - np.float32(center_xy[1])
        cols = np.arange(shape[1], dtype=np.float32) - np.float32(center_xy[0])
        dist = np.sqrt(rows[:, None] ** 2 + cols[None, :] ** 2)
        keep = dist < n_bands
        if valid is not None:
            keep &= valid
        d = dist[keep].astype(np.float64)
        band = dist[keep].astype(np.intp)  # np.bincount's own index type: no converted copy per call
        count = np.bincount(band, minlength=n_bands)[:n_bands]
        return cls(d, band, count, np.flatnonzero(keep.ravel()))

    def clipped_profile(
        self, values: np.ndarray, clip_sigma: float = 5.0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Band means, their standard errors and pixel counts, after rejecting outliers per band.

        A pixel more than ``clip_sigma`` robust standard deviations (1.4826 ×
        the median absolute deviation) from its band's median is left out:
        hot pixels and bioluminescent specks, which would otherwise bias the
        faint halo's bands. Bands whose pixels spread because the light
        changes across them (the disk's edge) have a wide spread and keep
        their pixels.
        """
        n = len(self.count)
        order = np.lexsort((values, self.band))
        v, b = values[order], self.band[order]
        starts = np.searchsorted(b, np.arange(n))
        ends = np.searchsorted(b, np.arange(n), side="right")
        mean, sem, count = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, dtype=np.int64)
        for i in range(n):
            x = v[starts[i] : ends[i]]
            if len(x) == 0:
                continue
            med = np.median(x)
            mad = 1.4826 * np.median(np.abs(x - med))
            keep = x if mad <= 0 else x[np.abs(x - med) <= clip_sigma * mad]
            count[i] = len(keep)
            mean[i] = keep.mean()
            sem[i] = keep.std(ddof=1) / np.sqrt(len(keep)) if len(keep) > 1 else np.nan
        return mean, sem, count

    def band_mean(self, values: np.ndarray) -> np.ndarray:
        """Mean of per-pixel ``values`` over each band (NaN for empty bands)."""
        total = np.bincount(self.band, weights=values, minlength=len(self.count))[: len(self.count)]
        with np.errstate(invalid="ignore", divide="ignore"):
            return total / self.count

    def disk_profile(self, radius_px: float, sigma_px: float) -> np.ndarray:
        """Band means of `blurred_disk` (fraction of the disk's radiance per band)."""
        return self.band_mean(self._blurred_values(radius_px, sigma_px))

    def _blurred_values(self, radius_px: float, sigma_px: float) -> np.ndarray:
        lo = max(radius_px - 0.5 - 7.0 * sigma_px - 1.0, 0.0)
        hi = radius_px + 0.5 + 7.0 * sigma_px + 1.0
        grid = np.arange(lo, hi + 0.02, 0.02)
        table = blurred_disk(grid, radius_px, sigma_px)
        return np.interp(self.distance_px, grid, table, left=1.0, right=0.0)

    def disk_path_moments(
        self, radius_px: float, sigma_px: float, distance_m: float, lem_radius_m: float, focal_px: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Band means of the blurred disk D times 1, δ and δ² (δ: `surface_path_excess_m`).

        The disk's band mean at any λ_att is then
        ``exp(-(L - a)/λ) · D0 · exp(-m/λ + v/(2λ²))`` with m = D1/D0 and
        v = D2/D0 - m² (cumulants to second order; δ/λ < 0.05 for any
        λ_att above 5 m, so the next term is below 10⁻⁵). The transmittance
        varies over the disk's radius, far more slowly than the PSF, so it
        multiplies the blurred disk at each pixel's own distance.
        """
        values = self._blurred_values(radius_px, sigma_px)
        delta = surface_path_excess_m(
            np.minimum(self.distance_px, radius_px), distance_m, lem_radius_m, focal_px
        )
        return self.band_mean(values), self.band_mean(values * delta), self.band_mean(values * delta * delta)


def disk_transmittance(
    moments: tuple[np.ndarray, np.ndarray, np.ndarray],
    distance_m: float,
    lem_radius_m: float,
    lambda_att_m: float,
) -> np.ndarray:
    """Band means of the blurred disk times exp(-s/λ_att), from `BandPixels.disk_path_moments`."""
    d0, d1, d2 = moments
    with np.errstate(invalid="ignore", divide="ignore"):
        m = np.where(d0 > 0, d1 / d0, 0.0)
        v = np.where(d0 > 0, np.maximum(d2 / d0 - m * m, 0.0), 0.0)
    lam = float(lambda_att_m)
    return math.exp(-(distance_m - lem_radius_m) / lam) * d0 * np.exp(-m / lam + v / (2.0 * lam * lam))
