"""Water optics: absorption, scattering, phase functions and the single-scattering halo.

Shared by the frame simulator (which draws the halo around the LEM) and the
analyses that interpret it, so both rest on one description of the water.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class WaterOptics:
    """Optical properties of water at one wavelength.

    ``lambda_sca_m`` is the total scattering length; a fraction
    ``rayleigh_fraction`` of the scattering is Rayleigh, the rest Mie with a
    Henyey-Greenstein phase function of mean cosine ``mie_g`` (⟨cos θ⟩).
    """

    lambda_abs_m: float
    lambda_sca_m: float
    mie_g: float = 0.93
    rayleigh_fraction: float = 0.17
    refractive_index: float = 1.35

    def __post_init__(self) -> None:
        if not (self.lambda_abs_m > 0 and self.lambda_sca_m > 0):
            raise ValueError(
                f"absorption and scattering lengths must be > 0, got "
                f"{self.lambda_abs_m} m and {self.lambda_sca_m} m"
            )
        if not (-1 < self.mie_g < 1):
            raise ValueError(f"mie_g (<cos theta>) must lie in (-1, 1), got {self.mie_g}")
        if not (0 <= self.rayleigh_fraction <= 1):
            raise ValueError(f"rayleigh_fraction must lie in [0, 1], got {self.rayleigh_fraction}")

    @property
    def lambda_att_m(self) -> float:
        """1/λ_att = 1/λ_abs + 1/λ_sca."""
        return 1.0 / (1.0 / self.lambda_abs_m + 1.0 / self.lambda_sca_m)

    @property
    def lambda_mie_m(self) -> float:
        return self.lambda_sca_m / (1.0 - self.rayleigh_fraction) if self.rayleigh_fraction < 1 else math.inf

    @property
    def lambda_rayleigh_m(self) -> float:
        return self.lambda_sca_m / self.rayleigh_fraction if self.rayleigh_fraction > 0 else math.inf


def henyey_greenstein_sr(cos_theta: np.ndarray, g: float) -> np.ndarray:
    """Henyey-Greenstein phase function per steradian (integrates to 1 over 4π)."""
    c = np.asarray(cos_theta, dtype=np.float64)
    return (1.0 - g * g) / (4.0 * np.pi * (1.0 + g * g - 2.0 * g * c) ** 1.5)


def rayleigh_sr(cos_theta: np.ndarray) -> np.ndarray:
    """Rayleigh phase function per steradian: (3 / 16π)(1 + cos²θ)."""
    c = np.asarray(cos_theta, dtype=np.float64)
    return 3.0 / (16.0 * np.pi) * (1.0 + c * c)


def phase_function_sr(cos_theta: np.ndarray, water: WaterOptics) -> np.ndarray:
    """Mixture of Mie (Henyey-Greenstein) and Rayleigh scattering, per steradian."""
    f = water.rayleigh_fraction
    return (1.0 - f) * henyey_greenstein_sr(cos_theta, water.mie_g) + f * rayleigh_sr(cos_theta)


def single_scatter_halo(
    psi_rad: np.ndarray,
    distance_m: float,
    water: WaterOptics,
    source_radius_m: float,
    n_steps: int = 200,
) -> np.ndarray:
    """Once-scattered radiance around a glowing sphere, relative to its surface radiance.

    A pinhole camera at ``distance_m`` from a sphere of radius
    ``source_radius_m`` and uniform surface radiance B looks along a direction
    at angle ``psi_rad`` from the sphere's centre. Light leaving the sphere
    reaches a point at distance ``s`` along that line of sight (distance
    ``r`` from the sphere's centre), scatters there by an angle Θ toward the
    camera and travels ``s`` back. The radiance collected is

        B ∫ ds  (1/λ_sca) p(Θ) Ω(r) exp(-(r + s) / λ_att)

    with Ω(r) the solid angle of the sphere seen from the scattering point and
    p the phase function. Near the sphere the light arrives from a wide cone
    of half-angle α = asin(a/r), so p is evaluated at an angle widened by α
    (a cone average of its forward peak). Lines of sight that hit the sphere
    stop there. Returns the halo radiance over B, attenuation included; the
    direct radiance of the disk over B is ``exp(-s / λ_att)``, s the path to
    the sphere's surface (`analysis.transport.disk.surface_path_m`).
    Multiple scattering is left out.
    """
    psi = np.atleast_1d(np.asarray(psi_rad, dtype=np.float64))[:, None]
    big_l, a = float(distance_m), float(source_radius_m)
    if big_l <= a:
        raise ValueError(f"distance {big_l} m must exceed the source radius {a} m")
    att = water.lambda_att_m
    s0 = big_l * np.cos(psi)  # foot of the perpendicular from the source
    d = big_l * np.sin(psi)  # closest approach of the line of sight
    hit = d < a
    s_hit = s0 - np.sqrt(np.maximum(a * a - d * d, 0.0))
    s_end = np.where(hit, s_hit, big_l + 8.0 * att)
    width = np.maximum(d, 0.05 * a)
    t0 = np.arcsinh((0.0 - s0) / width)
    t1 = np.arcsinh((s_end - s0) / width)
    u = (np.arange(n_steps) + 0.5) / n_steps
    t = t0 + (t1 - t0) * u[None, :]
    s = s0 + width * np.sinh(t)
    ds_dt = width * np.cosh(t) * (t1 - t0) / n_steps
    r = np.sqrt(np.maximum(s * s + big_l * big_l - 2.0 * s * big_l * np.cos(psi), a * a))
    cos_theta = np.clip((big_l * np.cos(psi) - s) / r, -1.0, 1.0)
    alpha = np.arcsin(np.clip(a / r, 0.0, 1.0))
    theta_eff = np.sqrt(np.arccos(cos_theta) ** 2 + 0.5 * alpha**2)
    omega = 2.0 * np.pi * (1.0 - np.cos(alpha))
    integrand = phase_function_sr(np.cos(np.minimum(theta_eff, np.pi)), water) * omega
    integrand *= np.exp(-(r + s) / att) / water.lambda_sca_m
    return np.sum(integrand * ds_dt, axis=1)
