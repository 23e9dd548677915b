"""The binned result of a transport run and its reweighting by exp(-k ℓ) (absorption, another λ_sca)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from analysis.transport.scene import ScatteringMedium, TransportConfig, TransportScene


@dataclass(frozen=True)
class TransportTally:
    """The binned result of one transport run.

    Arrays have shape ``(camera, component, order, band, path_bin)`` (see
    `analysis.transport.scene.N_COMPONENTS` for the two emission components);
    ``order`` 0 is the direct light, ``k`` the light scattered ``k`` times.
    ``sum_w`` is the radiance-weighted flux (in units of the LEM's surface
    radiance times sr), ``sum_wl`` and ``sum_wl2`` its first two path
    moments, ``sum_w2`` the sum of squared contributions (for errors). The
    path ℓ is the total path from the LEM's surface to the camera.
    ``group_w`` holds Σw of the orders >= 2 per independent group of
    batches, shape ``(group, camera, component, band)``: the scatter between
    groups measures the error where a few rare, heavy contributions make
    Σw² an underestimate.
    """

    scene: TransportScene
    medium: ScatteringMedium
    config: TransportConfig
    seed: int
    sum_w: np.ndarray = field(repr=False)
    sum_wl: np.ndarray = field(repr=False)
    sum_wl2: np.ndarray = field(repr=False)
    sum_w2: np.ndarray = field(repr=False)
    path_edges_m: np.ndarray = field(repr=False)
    group_w: np.ndarray = field(repr=False)

    def radiance(
        self, lambda_abs_m: float = math.inf, orders: slice | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Radiance per camera and band (uniform LEM, B₀ = 1) and its statistical error.

        Applies absorption ``exp(-ℓ / lambda_abs_m)`` at the simulated
        scattering length. ``orders`` selects scattering orders (default:
        the scattered light, orders >= 1).
        """
        sel = slice(1, None) if orders is None else orders
        k = 0.0 if math.isinf(lambda_abs_m) else 1.0 / lambda_abs_m
        value, var = path_reweight(self.sum_w, self.sum_wl, self.sum_wl2, self.sum_w2, k)
        value = value[:, :, sel].sum(axis=(1, 2))
        var = var[:, :, sel].sum(axis=(1, 2))
        omega = np.stack([self.scene.band_solid_angle_sr(c) for c in range(len(self.scene.cameras))])
        return value / omega, np.sqrt(var) / omega


def path_reweight(
    sum_w: np.ndarray, sum_wl: np.ndarray, sum_wl2: np.ndarray, sum_w2: np.ndarray, k_per_m: float
) -> tuple[np.ndarray, np.ndarray]:
    """Σ w·exp(-k ℓ) and its variance from per-bin path moments, summed over path bins.

    Within a bin the factor is expanded around the mean path:
    exp(-k ℓ̄)(1 + k² var(ℓ)/2), exact to second order in the bin's spread.
    Used for absorption (k = 1/λ_abs) and for moving to another scattering
    length (k gains 1/λ - 1/λ₀).
    """
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(sum_w != 0, sum_wl / sum_w, 0.0)
        spread = np.where(sum_w != 0, np.maximum(sum_wl2 / sum_w - mean * mean, 0.0), 0.0)
    factor = np.exp(-k_per_m * mean)
    value = (sum_w * factor * (1.0 + 0.5 * k_per_m * k_per_m * spread)).sum(axis=-1)
    var = (sum_w2 * factor * factor * (1.0 + 2.0 * k_per_m * k_per_m * spread)).sum(axis=-1)
    return value, var


@dataclass(frozen=True)
class PathMoments:
    """Per-bin path moments in sparse form, for fast reweighting by exp(-k ℓ).

    ``index`` maps each non-empty bin to a cell of an output array of shape
    ``out_shape`` (the path bins are summed over). `reweight` applies the
    second-order expansion of `path_reweight` with one `numpy.bincount`.
    """

    out_shape: tuple[int, ...]
    index: np.ndarray = field(repr=False)
    weight: np.ndarray = field(repr=False)
    mean_m: np.ndarray = field(repr=False)
    spread_m2: np.ndarray = field(repr=False)
    weight2: np.ndarray = field(repr=False)

    @classmethod
    def from_sums(
        cls, sum_w: np.ndarray, sum_wl: np.ndarray, sum_wl2: np.ndarray, sum_w2: np.ndarray
    ) -> PathMoments:
        """From sums with the path bins on the last axis."""
        out_shape = sum_w.shape[:-1]
        n_path = sum_w.shape[-1]
        nz = np.flatnonzero(sum_w.ravel() != 0)
        w = sum_w.ravel()[nz]
        mean = sum_wl.ravel()[nz] / w
        spread = np.maximum(sum_wl2.ravel()[nz] / w - mean * mean, 0.0)
        return cls(out_shape, nz // n_path, w, mean, spread, sum_w2.ravel()[nz])

    def reweight(self, k_per_m: float) -> tuple[np.ndarray, np.ndarray]:
        """Σ w·exp(-k ℓ) and its variance per output cell."""
        factor = np.exp(-k_per_m * self.mean_m)
        k2 = k_per_m * k_per_m
        size = int(np.prod(self.out_shape))
        value = np.bincount(
            self.index, weights=self.weight * factor * (1.0 + 0.5 * k2 * self.spread_m2), minlength=size
        )
        var = np.bincount(
            self.index,
            weights=self.weight2 * factor * factor * (1.0 + 2.0 * k2 * self.spread_m2),
            minlength=size,
        )
        return value.reshape(self.out_shape), var.reshape(self.out_shape)
