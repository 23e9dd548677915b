"""A halo made by another engine (Mitsuba 3), tabulated per camera distance, for the simulator to render.

`bench/mitsuba_halo.py` writes the tables (``.npz``): per camera distance
the halo h(ρ) (scattered radiance over the LEM's uniform surface radiance)
in radial bins, inside the disk in a few wide bins, none across the limb.
`HaloTable.at` turns one camera's bins into h(ψ) on any angle grid:

* inside the disk a + bρ² (flat at the centre) fitted to the inner bins by
  their errors (the other engine's direct light is a noisy stochastic hit,
  so single inner bins scatter);
* across the limb (±2 px) linear from that line to the first outer bin;
* outside, linear between the bins, and beyond the last one a power law
  fitted to the outer third of the bins (the frame's corners).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.scattering import WaterOptics
from analysis.transport.disk import disk_radius_px
from analysis.transport.scene import LEM_RADIUS_M


@dataclass(frozen=True)
class HaloTable:
    """h(ρ) per camera distance from another engine, and the water and geometry it was made for."""

    water: WaterOptics
    focal_px: float
    distances_m: tuple[float, ...]
    rho_px: tuple[np.ndarray, ...]
    halo: tuple[np.ndarray, ...]
    halo_err: tuple[np.ndarray, ...]

    @classmethod
    def load(cls, path: str | Path) -> HaloTable:
        with np.load(path) as z:
            n = len(z["distances_m"])
            water = WaterOptics(
                float(z["lambda_abs_m"]),
                float(z["lambda_sca_m"]),
                mie_g=float(z["mie_g"]),
                rayleigh_fraction=float(z["rayleigh_fraction"]),
            )
            return cls(
                water,
                float(z["focal_px"]),
                tuple(float(d) for d in z["distances_m"]),
                tuple(np.asarray(z[f"rho_px_{k}"], float) for k in range(n)),
                tuple(np.asarray(z[f"halo_{k}"], float) for k in range(n)),
                tuple(np.asarray(z[f"halo_err_{k}"], float) for k in range(n)),
            )

    def camera(self, distance_m: float) -> int:
        for k, d in enumerate(self.distances_m):
            if abs(d - distance_m) <= 1e-3:
                return k
        raise ValueError(f"the halo table holds cameras at {self.distances_m} m, not at {distance_m} m")

    def at(self, distance_m: float, psi_rad: np.ndarray) -> np.ndarray:
        """h at angles ``psi_rad`` from the LEM's centre for the camera at ``distance_m``."""
        k = self.camera(distance_m)
        rho, h, err = self.rho_px[k], self.halo[k], self.halo_err[k]
        r_disk = disk_radius_px(distance_m, LEM_RADIUS_M, self.focal_px)
        inner, outer = rho < r_disk, rho > r_disk
        if inner.sum() >= 2:  # flat at the centre: a + b ρ²
            b, a = np.polyfit(rho[inner] ** 2, h[inner], 1, w=1.0 / err[inner])
        else:
            b, a = 0.0, float(h[outer][0])
        x_in = np.linspace(0.0, r_disk - 2.0, 16)
        x = np.concatenate([x_in, rho[outer]])
        y = np.concatenate([a + b * x_in**2, h[outer]])
        want = np.tan(np.asarray(psi_rad, float)) * self.focal_px
        out = np.interp(want, x, y)
        tail = rho[outer][-max(3, outer.sum() // 3) :]
        vals = h[outer][-len(tail) :]
        beyond = want > x[-1]
        if beyond.any() and np.all(vals > 0):
            p, c = np.polyfit(np.log(tail), np.log(vals), 1)
            out[beyond] = np.exp(c) * want[beyond] ** p
        return out

    def describe(self) -> str:
        w = self.water
        return (
            f"λ_abs {w.lambda_abs_m:g} m, λ_sca {w.lambda_sca_m:g} m, ⟨cos θ⟩ {w.mie_g:g}, Rayleigh "
            f"{w.rayleigh_fraction:g}, cameras at {', '.join(f'{d:g}' for d in self.distances_m)} m, "
            f"focal length {self.focal_px:.0f} px"
        )
