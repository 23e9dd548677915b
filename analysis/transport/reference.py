"""Quadrature references for the transport: the exact once-scattered radiance of a glowing sphere.

`analysis.scattering.single_scatter_halo` (the simulator's default halo)
approximates the phase function over the sphere's apparent disk by a cone
average and attenuates from the sphere's centre. This module integrates the
same physics without those approximations, slowly but exactly, so the Monte
Carlo can be checked against it and the approximation's error measured.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import roots_legendre

from analysis.transport.sampling import mixed_phase_sr


def single_scatter_radiance(
    psi_rad: float,
    distance_m: float,
    lem_radius_m: float,
    lambda_sca_m: float,
    lambda_abs_m: float,
    mie_g: float,
    rayleigh_fraction: float,
    *,
    n_line: int = 400,
    n_cap: int = 48,
) -> float:
    """Once-scattered radiance (LEM surface radiance = 1) seen at angle ψ from the LEM's centre.

    The camera at ``distance_m`` looks along a line at angle ψ. A point at
    distance ``s`` on that line receives the light of every visible surface
    point y of the sphere (radiance 1, attenuated over |x - y|), scatters it
    toward the camera with the phase function (per sr) at the angle between
    the light's direction and the line of sight, with probability
    ds/λ_sca, and the result is attenuated over ``s``::

        L(ψ) = ∫ ds/λ_sca e^(-s/λ_att) ∫_cap dω p(Θ(ω)) e^(-|x - y(ω)|/λ_att)

    The cap integral runs over the cone of directions from x toward the
    sphere (Gauss-Legendre in cos β and φ); the line integral uses the
    substitution s = s₀ + w·sinh(t), which packs nodes where the line passes
    the sphere. Lines of sight that hit the sphere end there.
    """
    a, big_l = lem_radius_m, distance_m
    lam_att = 1.0 / (1.0 / lambda_abs_m + 1.0 / lambda_sca_m)
    cam = np.array([0.0, 0.0, big_l])
    view = np.array([math.sin(psi_rad), 0.0, -math.cos(psi_rad)])  # from the camera toward the LEM
    s0 = big_l * math.cos(psi_rad)
    d_min = big_l * math.sin(psi_rad)
    s_end = s0 - math.sqrt(a * a - d_min * d_min) if d_min < a else big_l + 12.0 * lam_att
    width = max(d_min, 0.05 * a)
    t0, t1 = math.asinh((0.0 - s0) / width), math.asinh((s_end - s0) / width)
    u, wu = roots_legendre(n_line)
    t = 0.5 * (t1 - t0) * (u + 1.0) + t0
    s = s0 + width * np.sinh(t)
    ds = width * np.cosh(t) * 0.5 * (t1 - t0) * wu
    x = cam[None, :] + s[:, None] * view[None, :]
    r = np.linalg.norm(x, axis=1)
    cos_alpha = np.sqrt(np.maximum(1.0 - (a / r) ** 2, 0.0))
    # Cap: cos β in [cos α, 1] around the direction from x to the centre, φ in [0, 2π).
    cb_nodes, cb_w = roots_legendre(n_cap)
    ph_nodes, ph_w = roots_legendre(n_cap)
    phi = math.pi * (ph_nodes + 1.0)
    w_phi = math.pi * ph_w
    total = 0.0
    for i in range(len(s)):
        axis = -x[i] / r[i]
        ca = cos_alpha[i]
        cos_b = 0.5 * (1.0 - ca) * (cb_nodes + 1.0) + ca
        w_b = 0.5 * (1.0 - ca) * cb_w
        sin_b = np.sqrt(np.maximum(1.0 - cos_b**2, 0.0))
        e1 = np.cross(axis, [0.0, 1.0, 0.0])
        if np.linalg.norm(e1) < 1e-9:
            e1 = np.cross(axis, [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        toward = cos_b[:, None, None] * axis + sin_b[:, None, None] * (
            np.cos(phi)[None, :, None] * e1 + np.sin(phi)[None, :, None] * e2
        )  # (n_b, n_phi, 3): from x toward the sphere
        dist = r[i] * cos_b - np.sqrt(np.maximum(a * a - r[i] ** 2 * (1.0 - cos_b**2), 0.0))
        light_dir = -toward  # the light travels from the sphere to x
        cos_theta = light_dir @ (-view)  # -view points from x back to the camera
        integrand = mixed_phase_sr(cos_theta, mie_g, rayleigh_fraction) * np.exp(-dist / lam_att)[:, None]
        total += ds[i] * math.exp(-s[i] / lam_att) * float(w_b @ integrand @ w_phi)
    return total / lambda_sca_m
