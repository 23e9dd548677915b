"""What the photon transport simulates: the LEM, the cameras on its axis and the water's scattering.

The LEM is a sphere at the origin. Cameras sit on the z axis: a camera with
``side = +1`` at ``z = +distance_m`` looks at the LEM's ``+z`` hemisphere
(the near camera in T-REX), one with ``side = -1`` at ``z = -distance_m``
at the ``-z`` hemisphere (the far camera, on the other side of the LEM on
the same vertical cable).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: Radius of the T-REX LEM sphere (0.43 m diameter).
LEM_RADIUS_M = 0.215


@dataclass(frozen=True)
class CameraSite:
    """A pinhole camera on the LEM's axis.

    ``focal_px`` (focal length in pixels) turns the angle ψ between the
    LEM's centre and a direction into the image distance ``focal_px·tan ψ``
    from the LEM's image: the radius of the 1-pixel bands of the profiles.
    """

    name: str
    distance_m: float
    side: int
    focal_px: float

    def __post_init__(self) -> None:
        if not self.distance_m > 0:
            raise ValueError(f"distance_m of camera {self.name} must be > 0, got {self.distance_m}")
        if self.side not in (1, -1):
            raise ValueError(f"side of camera {self.name} must be +1 or -1, got {self.side}")
        if not self.focal_px > 0:
            raise ValueError(f"focal_px of camera {self.name} must be > 0, got {self.focal_px}")

    @property
    def z_m(self) -> float:
        return self.side * self.distance_m


def band_edges_px(n_fine: int, outer_px: float | None = None, n_outer: int = 0) -> tuple[float, ...]:
    """Radii of the angular bins in pixels: 1-pixel bands out to ``n_fine``, then wider ones.

    The fine bands are the image's radius bands (band ``i`` covers
    ``[i, i + 1)`` px). For the simulator, which needs the halo over the
    whole frame, ``n_outer`` logarithmically widening bins continue to
    ``outer_px``.
    """
    if n_fine < 1:
        raise ValueError(f"n_fine must be >= 1, got {n_fine}")
    edges = list(np.arange(n_fine + 1, dtype=np.float64))
    if outer_px is not None and n_outer > 0:
        if not outer_px > n_fine:
            raise ValueError(f"outer_px ({outer_px}) must exceed n_fine ({n_fine})")
        edges += list(np.geomspace(n_fine, outer_px, n_outer + 1)[1:])
    return tuple(float(e) for e in edges)


#: The emission components: light leaving the LEM in a direction with z-cosine μ counts
#: (1 + μ)/2 toward component 0 (the +z side, the near camera) and (1 - μ)/2 toward
#: component 1 (the -z side, the far camera). See `analysis.transport.templates.EmissionProfile`.
N_COMPONENTS = 2
#: How the two components share light leaving at z-cosine μ: ``linear`` (1 + μ)/2 : (1 - μ)/2, the
#: model the fit uses; ``hemispheres`` (1 + sin(πμ/2))/2 : (1 - sin(πμ/2))/2, the same at the poles
#: and the equator but flat near the poles: each hemisphere's LEDs keep their own brightness and
#: the change happens near the equator (the alternative of the systematic budget).
EMISSION_SHAPES = ("linear", "hemispheres")


def emission_shares(mu: np.ndarray, shape: str = "linear") -> tuple[np.ndarray, np.ndarray]:
    """The shares of components 0 (+z side) and 1 (-z side) of light emitted at z-cosine ``mu``."""
    mu = np.asarray(mu, dtype=np.float64)
    if shape == "linear":
        s0 = 0.5 * (1.0 + mu)
    elif shape == "hemispheres":
        s0 = 0.5 * (1.0 + np.sin(0.5 * np.pi * mu))
    else:
        raise ValueError(f"emission shape {shape!r} unknown (one of {', '.join(EMISSION_SHAPES)})")
    return s0, 1.0 - s0


@dataclass(frozen=True)
class TransportScene:
    """The LEM, its cameras and the angular bins they are tallied in.

    The LEM's light is kept in two components by its emission direction (see
    `N_COMPONENTS`), so any emission profile linear in the cosine of the
    emission polar angle, such as one pinned by the far/near ratio I0'/I0,
    can be applied afterwards without simulating again.
    """

    cameras: tuple[CameraSite, ...]
    band_edges_px: tuple[float, ...]
    lem_radius_m: float = LEM_RADIUS_M
    emission_shape: str = "linear"

    def __post_init__(self) -> None:
        if self.emission_shape not in EMISSION_SHAPES:
            raise ValueError(
                f"emission_shape {self.emission_shape!r} unknown (one of {', '.join(EMISSION_SHAPES)})"
            )
        if not self.cameras:
            raise ValueError("cameras: at least one camera is needed")
        if not self.lem_radius_m > 0:
            raise ValueError(f"lem_radius_m must be > 0, got {self.lem_radius_m}")
        for cam in self.cameras:
            if cam.distance_m <= 2 * self.lem_radius_m:
                raise ValueError(
                    f"camera {cam.name} at {cam.distance_m} m is too close to the LEM "
                    f"(radius {self.lem_radius_m} m)"
                )
        edges = np.asarray(self.band_edges_px)
        if edges.ndim != 1 or len(edges) < 2 or edges[0] != 0 or np.any(np.diff(edges) <= 0):
            raise ValueError("band_edges_px must start at 0 and increase")

    @property
    def n_bands(self) -> int:
        return len(self.band_edges_px) - 1

    @property
    def n_components(self) -> int:
        return N_COMPONENTS

    def psi_edges_rad(self, camera: int) -> np.ndarray:
        """Angular edges of the bands of one camera: ψ = atan(r / focal_px)."""
        return np.arctan(np.asarray(self.band_edges_px) / self.cameras[camera].focal_px)

    def band_solid_angle_sr(self, camera: int) -> np.ndarray:
        """Solid angle of each annular band, 4π(sin²(ψ₁/2) - sin²(ψ₀/2)) (stable for small ψ)."""
        s2 = np.sin(self.psi_edges_rad(camera) / 2.0) ** 2
        return 4.0 * np.pi * np.diff(s2)

    def disk_radius_px(self, camera: int) -> float:
        """Radius of the LEM's image: f·a / sqrt(L² - a²) (the simulator's pinhole formula)."""
        cam = self.cameras[camera]
        a, big_l = self.lem_radius_m, cam.distance_m
        return cam.focal_px * a / math.sqrt(big_l * big_l - a * a)


@dataclass(frozen=True)
class ScatteringMedium:
    """The water's scattering: length, Mie ⟨cos θ⟩ and the Rayleigh share.

    Absorption is not simulated: it multiplies a photon's weight by
    exp(-path/λ_abs), which is applied afterwards from the recorded paths.
    """

    lambda_sca_m: float
    mie_g: float = 0.93
    rayleigh_fraction: float = 0.17

    def __post_init__(self) -> None:
        if not self.lambda_sca_m > 0:
            raise ValueError(f"lambda_sca_m must be > 0, got {self.lambda_sca_m}")
        if not -1 < self.mie_g < 1:
            raise ValueError(f"mie_g must lie in (-1, 1), got {self.mie_g}")
        if not 0 <= self.rayleigh_fraction <= 1:
            raise ValueError(f"rayleigh_fraction must lie in [0, 1], got {self.rayleigh_fraction}")


@dataclass(frozen=True)
class TransportConfig:
    """How the Monte Carlo runs.

    ``natural_fraction`` is the share of flights drawn the natural way (phase
    function and exponential free path); the rest are drawn into the narrow
    cone each camera sees (see `analysis.transport.engine`), except that from
    the second flight on ``guided_fraction`` of them fly the natural free
    path in a direction drawn from the Mie forward peak around the direction
    to a camera (double and triple forward scattering toward a camera, which
    the cone's vertices, drawn without regard to where the photon came from,
    find only rarely: the higher orders' heavy tail). Photons stop after
    ``max_order`` scatterings or ``path_max_m`` of path: what they would still
    add to the images is a faint, nearly flat veil.
    """

    n_photons: int = 200_000
    max_order: int = 6
    path_max_m: float = 400.0
    batch_size: int = 25_000
    natural_fraction: float = 0.4
    guided_fraction: float = 0.3
    direct_samples: int = 50_000
    n_path_bins: int = 64
    path_bins_min_m: float = 0.01

    def __post_init__(self) -> None:
        if self.n_photons < 1 or self.batch_size < 1:
            raise ValueError(
                f"n_photons and batch_size must be >= 1, got {self.n_photons}, {self.batch_size}"
            )
        if not 1 <= self.max_order <= 64:
            raise ValueError(f"max_order must lie in [1, 64], got {self.max_order}")
        if not 0 < self.natural_fraction <= 1:
            raise ValueError(f"natural_fraction must lie in (0, 1], got {self.natural_fraction}")
        if not 0 <= self.guided_fraction <= 1 - self.natural_fraction:
            raise ValueError(
                f"guided_fraction must lie in [0, 1 - natural_fraction], got {self.guided_fraction}"
            )
        if not self.path_max_m > 0:
            raise ValueError(f"path_max_m must be > 0, got {self.path_max_m}")
        if self.n_path_bins < 4:
            raise ValueError(f"n_path_bins must be >= 4, got {self.n_path_bins}")

    def path_edges_m(self) -> np.ndarray:
        """Edges of the excess-path bins (path minus the shortest possible path to the camera)."""
        inner = np.geomspace(self.path_bins_min_m, self.path_max_m, self.n_path_bins - 1)
        return np.concatenate([[0.0], inner, [np.inf]])
