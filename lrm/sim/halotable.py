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

A table also says what made it (`PhaseTruth`: the phase function's family
and parameters, the particles' and the whole's mean cosine, b_b/b) and, from
issue 35's tables on, its wavelength; the two older tables (HG 0.93 + 17 %
Rayleigh) carry neither and read as HG at 460 nm.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.scattering import WaterOptics
from analysis.transport.disk import disk_radius_px
from analysis.transport.scene import LEM_RADIUS_M


@dataclass(frozen=True)
class PhaseTruth:
    """The phase function a table was rendered with: the truth a fit of its frames is judged by.

    ``family`` "hg" (Henyey-Greenstein g + Rayleigh 1 + cos²θ, the fit's own
    family), "fournier-forand" or "petzold-like" (particles mixed with
    seawater's depolarised Rayleigh 1 + 0.835 cos²θ); ``particle_mean_cos``
    the particles' ⟨cos θ⟩ (HG: g); ``mean_cos_theta`` the whole's,
    (1 − rayleigh_share)·particle_mean_cos (Rayleigh's mean cosine is 0);
    ``backscatter_fraction`` b_b/b of the whole (None where not recorded).
    """

    family: str
    params: tuple[tuple[str, float], ...]
    particle_mean_cos: float
    rayleigh_share: float
    backscatter_fraction: float | None = None
    fraction_within_1deg: float | None = None

    @property
    def mean_cos_theta(self) -> float:
        return (1.0 - self.rayleigh_share) * self.particle_mean_cos

    def to_dict(self) -> dict[str, object]:
        return {
            "family": self.family,
            "params": dict(self.params),
            "g_mie": self.particle_mean_cos,
            "rayleigh_share": self.rayleigh_share,
            "mean_cos_theta": self.mean_cos_theta,
            "mean_cos_theta_definition": "(1 - rayleigh_share) * g_mie; Rayleigh's mean cosine is 0",
            "backscatter_fraction": self.backscatter_fraction,
            "fraction_within_1deg": self.fraction_within_1deg,
        }


@dataclass(frozen=True)
class HaloTable:
    """h(ρ) per camera distance from another engine, and the water and geometry it was made for."""

    water: WaterOptics
    focal_px: float
    distances_m: tuple[float, ...]
    rho_px: tuple[np.ndarray, ...]
    halo: tuple[np.ndarray, ...]
    halo_err: tuple[np.ndarray, ...]
    wavelength_nm: int | None = None
    phase: PhaseTruth | None = None
    name: str = ""
    spp: int | None = None
    seconds: tuple[float, ...] = ()

    @classmethod
    def load(cls, path: str | Path) -> HaloTable:
        with np.load(path) as z:
            n = len(z["distances_m"])
            g, f = float(z["mie_g"]), float(z["rayleigh_fraction"])
            water = WaterOptics(
                float(z["lambda_abs_m"]), float(z["lambda_sca_m"]), mie_g=g, rayleigh_fraction=f
            )
            if "phase_family" in z.files:
                names = [str(x) for x in z["phase_param_names"]]
                phase = PhaseTruth(
                    str(z["phase_family"]),
                    tuple(zip(names, (float(v) for v in z["phase_param_values"]), strict=True)),
                    g,
                    f,
                    float(z["backscatter_fraction"]),
                    float(z["fraction_within_1deg"]),
                )
            else:  # the first two tables: HG + Rayleigh by blendphase
                phase = PhaseTruth("hg", (("g", g),), g, f)
            return cls(
                water,
                float(z["focal_px"]),
                tuple(float(d) for d in z["distances_m"]),
                tuple(np.asarray(z[f"rho_px_{k}"], float) for k in range(n)),
                tuple(np.asarray(z[f"halo_{k}"], float) for k in range(n)),
                tuple(np.asarray(z[f"halo_err_{k}"], float) for k in range(n)),
                int(z["wavelength_nm"]) if "wavelength_nm" in z.files else None,
                phase,
                Path(path).stem,
                int(z["spp"]) if "spp" in z.files else None,
                tuple(float(x) for x in z["seconds"]) if "seconds" in z.files else (),
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
        family = f"{self.phase.family} " if self.phase is not None and self.phase.family != "hg" else ""
        at = f"{self.wavelength_nm} nm: " if self.wavelength_nm is not None else ""
        return (
            f"{at}λ_abs {w.lambda_abs_m:g} m, λ_sca {w.lambda_sca_m:g} m, {family}⟨cos θ⟩ {w.mie_g:g}, "
            f"Rayleigh {w.rayleigh_fraction:g}, cameras at {', '.join(f'{d:g}' for d in self.distances_m)} "
            "m, "
            f"focal length {self.focal_px:.0f} px"
        )


def tables_by_wavelength(tables: list[HaloTable] | tuple[HaloTable, ...]) -> dict[int, HaloTable]:
    """The tables keyed by their wavelength; refuses a table without one, or two at one wavelength."""
    out: dict[int, HaloTable] = {}
    for t in tables:
        if t.wavelength_nm is None:
            raise ValueError(
                f"the halo table {t.name or t.describe()} records no wavelength (one of the first two "
                "tables, made for 460 nm): give it alone, or re-render it with bench/mitsuba_halo.py"
            )
        if t.wavelength_nm in out:
            raise ValueError(
                f"two halo tables at {t.wavelength_nm} nm: {out[t.wavelength_nm].name}, {t.name}"
            )
        out[t.wavelength_nm] = t
    return out
