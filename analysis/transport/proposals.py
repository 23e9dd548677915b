"""Where the transport's forced and guided flights put their vertices (`analysis.transport.engine`).

The cone proposal places a vertex in the cone a camera sees; the emission point of a forced
vertex is drawn over the LEM's visible cap or along the Mie forward peak; `strategies` picks
each flight's way (natural, forced into a camera's cone, guided toward a camera). Each density
is known in closed form so that the engine can weight its flights by the balance heuristic.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from analysis.transport.sampling import rotate, sample_hg_cos
from analysis.transport.scene import CameraSite

#: Mixture of the axial position in the cone proposal: ∝ 1/t² beyond the forward peak,
#: uniform on [0, L], log-uniform on [a, L].
AXIS_SHARES = (0.5, 0.25, 0.25)
#: Share of forced first vertices whose emission point is uniform over the visible cap (rest: guided).
CAP_UNIFORM_SHARE = 0.5
#: Share of cone-proposal angles drawn uniformly over the fine bands (the rest over the outer bins).
INNER_PSI_SHARE = 0.75


@dataclass(frozen=True)
class ConeProposal:
    """A density that places vertices in the cone a camera sees.

    The angle ψ at which the camera sees the point is drawn uniformly on
    [0, ψ_inner] (equal counts per one-pixel band) or, with weight
    ``1 - INNER_PSI_SHARE``, log-uniformly on [ψ_inner, ψ_outer]; the
    azimuth uniformly. Then the distance ``t`` from the LEM's centre along
    the axis: light scattered at ``t`` reaches the camera at ψ after turning
    by Θ ≈ ψL/t, and the Mie phase function is flat for Θ below ~(1 - g) and
    falls steeply beyond, so the once-scattered radiance gathers along the
    line of sight with density ∝ 1/t² from ``t₀ = ψL/(1 - g)`` on. Half of
    the points follow that, a quarter are uniform on [0, L] and a quarter
    log-uniform on [a, L] (wide-angle and Rayleigh scattering near the LEM).
    ``pdf`` is the density per unit volume.
    """

    camera: CameraSite
    lem_radius_m: float
    psi_inner_rad: float
    psi_outer_rad: float
    forward_width_rad: float = 0.07

    @property
    def _has_outer(self) -> bool:
        return self.psi_outer_rad > self.psi_inner_rad * 1.0001

    def _t0(self, psi: np.ndarray) -> np.ndarray:
        big_l = self.camera.distance_m
        return np.clip(psi * big_l / self.forward_width_rad, self.lem_radius_m, 0.5 * big_l)

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        big_l, a = self.camera.distance_m, self.lem_radius_m
        xi = rng.random(n)
        if self._has_outer:
            inner = rng.random(n) < INNER_PSI_SHARE
            psi = np.where(
                inner,
                self.psi_inner_rad * xi,
                self.psi_inner_rad * (self.psi_outer_rad / self.psi_inner_rad) ** xi,
            )
        else:
            psi = self.psi_outer_rad * xi
        t0 = self._t0(psi)
        xi = rng.random(n)
        pick = rng.random(n)
        inv = 1.0 / (1.0 / t0 - xi * (1.0 / t0 - 1.0 / big_l))
        t = np.where(
            pick < AXIS_SHARES[0],
            inv,
            np.where(pick < AXIS_SHARES[0] + AXIS_SHARES[1], big_l * xi, a * (big_l / a) ** xi),
        )
        u = big_l - t
        b = u * np.tan(psi)
        phi = 2.0 * np.pi * rng.random(n)
        return np.column_stack([b * np.cos(phi), b * np.sin(phi), self.camera.side * t])

    def pdf(self, x: np.ndarray) -> np.ndarray:
        big_l, a = self.camera.distance_m, self.lem_radius_m
        t = self.camera.side * x[:, 2]
        u = big_l - t
        b = np.hypot(x[:, 0], x[:, 1])
        ok = (t >= 0) & (u > 0)
        t_safe = np.where(ok, t, 1.0)
        u_safe = np.where(ok, u, 1.0)
        psi = np.arctan2(b, u_safe)
        t0 = self._t0(psi)
        p_t = (
            AXIS_SHARES[0]
            * np.where(t_safe >= t0, 1.0 / (np.maximum(t_safe, t0) ** 2 * (1.0 / t0 - 1.0 / big_l)), 0.0)
            + AXIS_SHARES[1] / big_l
            + AXIS_SHARES[2] * np.where(t_safe >= a, 1.0 / (np.maximum(t_safe, a) * math.log(big_l / a)), 0.0)
        )
        if self._has_outer:
            span = math.log(self.psi_outer_rad / self.psi_inner_rad)
            p_psi = np.where(
                psi < self.psi_inner_rad,
                INNER_PSI_SHARE / self.psi_inner_rad,
                np.where(
                    psi < self.psi_outer_rad,
                    (1.0 - INNER_PSI_SHARE) / (np.maximum(psi, 1e-300) * span),
                    0.0,
                ),
            )
        else:
            p_psi = np.where(psi < self.psi_outer_rad, 1.0 / self.psi_outer_rad, 0.0)
        b_safe = np.maximum(b, 1e-300)
        dpsi_db = u_safe / (u_safe * u_safe + b_safe * b_safe)
        return np.where(ok, p_t * p_psi * dpsi_db / (2.0 * np.pi * b_safe), 0.0)


def cap_solid_angle_sr(radius_m: float, distance_m: np.ndarray) -> np.ndarray:
    """Solid angle of a sphere of radius a seen from distance r: 2π(1 - cos α), sin α = a/r.

    Written as 2π (a/r)² / (1 + cos α), which keeps its precision far away,
    where 1 - cos α would cancel to zero.
    """
    s2 = np.minimum((radius_m / np.asarray(distance_m)) ** 2, 1.0)
    return 2.0 * np.pi * s2 / (1.0 + np.sqrt(1.0 - s2))


def emission_point_for(
    rng: np.random.Generator, x: np.ndarray, camera: CameraSite, a: float, mie_g: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface points lighting the forced vertices ``x``: the LEM point each photon came from.

    Half are uniform over the sphere's apparent cap seen from x; half follow
    the Mie forward peak: the light's direction is drawn from the
    Henyey-Greenstein distribution around the direction from x to the
    camera, and traced back to the sphere (misses are wasted). Near the LEM
    the cap is wide and only its part that shines almost straight toward the
    camera matters; the guided half finds it. Returns the points, the unit
    vectors from x toward them and whether the draw is usable.
    """
    m = len(x)
    r = np.linalg.norm(x, axis=1)
    outside = r > a * (1.0 + 1e-9)
    r_safe = np.where(outside, r, 2.0 * a)
    x_safe = np.where(outside[:, None], x, np.array([0.0, 0.0, 2.0 * a]))
    cos_alpha = np.sqrt(np.maximum(1.0 - (a / r_safe) ** 2, 0.0))
    toward = np.empty((m, 3))
    uniform = rng.random(m) < CAP_UNIFORM_SHARE
    k = int(uniform.sum())
    if k:
        cos_beta = cos_alpha[uniform] + (1.0 - cos_alpha[uniform]) * rng.random(k)
        axis = -x_safe[uniform] / r_safe[uniform, None]
        toward[uniform] = rotate(axis, cos_beta, 2.0 * np.pi * rng.random(k))
    g = ~uniform
    k = m - int(uniform.sum())
    if k:
        to_cam = np.array([0.0, 0.0, camera.z_m]) - x_safe[g]
        to_cam /= np.linalg.norm(to_cam, axis=1)[:, None]
        light = rotate(to_cam, sample_hg_cos(rng.random(k), mie_g), 2.0 * np.pi * rng.random(k))
        toward[g] = -light
    # Nearest intersection of x + t·toward with the sphere.
    b = np.einsum("ij,ij->i", x_safe, toward)
    disc = b * b - (r_safe * r_safe - a * a)
    hit = outside & (disc >= 0) & (b < 0)
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    y = x_safe + t[:, None] * toward
    return y, toward, hit


def strategies(
    rng: np.random.Generator, n: int, q_nat: float, n_cones: int, q_guided: float = 0.0
) -> np.ndarray:
    """0 for a natural flight, ``c + 1`` for one forced into camera ``c``'s cone, ``n_cones + c + 1``
    for one guided toward camera ``c`` (a share ``q_guided`` of all flights)."""
    xi = rng.random(n)
    out = np.zeros(n, dtype=np.int64)
    q_forced = 1.0 - q_nat - q_guided
    if q_forced > 0:
        cone = (xi >= q_nat) & (xi < q_nat + q_forced)
        out[cone] = 1 + np.minimum(((xi[cone] - q_nat) / q_forced * n_cones).astype(np.int64), n_cones - 1)
    if q_guided > 0:
        guided = xi >= q_nat + q_forced
        out[guided] = (
            1
            + n_cones
            + np.minimum(((xi[guided] - q_nat - q_forced) / q_guided * n_cones).astype(np.int64), n_cones - 1)
        )
    return out


def unit_toward(camera: CameraSite, x: np.ndarray) -> np.ndarray:
    """Unit vectors from the points ``x`` toward the camera."""
    v = np.array([0.0, 0.0, camera.z_m]) - x
    return v / np.maximum(np.linalg.norm(v, axis=1), 1e-300)[:, None]
