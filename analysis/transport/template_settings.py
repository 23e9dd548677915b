"""What a template grid is built for, and one halo read from it (`analysis.transport.templates`).

`TemplateSettings` holds the geometry (cameras, LEM, bands), the phase function's nodes and the
Monte Carlo's settings; `EmissionProfile` how the LEM's emission is shared between its two
components; `HaloTemplate` the scattered light of one water at every camera and band.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from analysis.transport.scene import (
    LEM_RADIUS_M,
    CameraSite,
    TransportConfig,
    TransportScene,
    band_edges_px,
)

#: Default scattering-length nodes (m): turbid to clear water, neighbours within a factor ~1.65.
DEFAULT_LAMBDA_SCA_NODES_M: tuple[float, ...] = (12.0, 20.0, 33.0, 55.0, 90.0, 150.0, 250.0)


def band_centres_px(edges_px: np.ndarray) -> np.ndarray:
    """The area centroids of annular bands with these edges (px): (2/3)(r₁³ - r₀³)/(r₁² - r₀²)."""
    e = np.asarray(edges_px, dtype=np.float64)
    return (2.0 / 3.0) * (e[1:] ** 3 - e[:-1] ** 3) / (e[1:] ** 2 - e[:-1] ** 2)


@dataclass(frozen=True)
class EmissionProfile:
    """The LEM's intensity as a function of the emission direction's polar angle.

    Intensity ∝ (1 + μ)/2 + (I0'/I0)(1 - μ)/2, with μ the cosine of the angle
    between the emission direction and the direction to the near camera:
    1 toward the near camera, ``far_near_ratio`` toward the far one, linear
    in μ between. Both cameras then see uniform disks, and the ratio is the
    lab-calibrated I0'/I0. ``far_near_ratio = 1`` is the uniform LEM.
    """

    far_near_ratio: float = 1.0

    def __post_init__(self) -> None:
        if not self.far_near_ratio > 0:
            raise ValueError(f"far_near_ratio (I0'/I0) must be > 0, got {self.far_near_ratio}")

    def weights(self) -> np.ndarray:
        """Weights of the two emission components (toward the near side, toward the far side)."""
        return np.array([1.0, self.far_near_ratio])

    def intensity(self, cos_theta: np.ndarray) -> np.ndarray:
        """Relative intensity at emission polar angle θ (from the near camera's direction)."""
        mu = np.asarray(cos_theta, dtype=np.float64)
        return 0.5 * (1.0 + mu) + self.far_near_ratio * 0.5 * (1.0 - mu)


@dataclass(frozen=True)
class TemplateCamera:
    """A camera of the templates: its name, distance and side (+1 near side, -1 far side)."""

    name: str
    distance_m: float
    side: int = 1


@dataclass(frozen=True)
class TemplateSettings:
    """Everything a template grid depends on, except the water's lengths.

    ``n_bands`` one-pixel bands (the image profile's bands) are tabulated per
    camera; ``outer_px``/``n_outer`` add wider bins out to the frame's corner
    for the simulator. The Monte Carlo of the higher orders tallies bins of
    ``mc_band_px`` pixels (interpolated onto the bands: multiply scattered
    light is smooth) with ``n_photons`` per node. With ``mc_phase`` =
    (⟨cos θ⟩, Rayleigh share) one Monte Carlo run per scattering-length node,
    sampled with that phase function, is reweighted to every ⟨cos θ⟩ node
    (`analysis.transport.engine.run_transport_reweighted`): the nodes share
    their photons, so the halo's change between them is nearly free of
    Monte Carlo noise (what a fit of ⟨cos θ⟩ needs); None: a run per node.
    """

    cameras: tuple[TemplateCamera, ...]
    focal_px: float
    n_bands: int = 168
    outer_px: float | None = None
    n_outer: int = 0
    lem_radius_m: float = LEM_RADIUS_M
    rayleigh_fraction: float = 0.17
    refractive_index: float = 1.35
    lambda_sca_nodes_m: tuple[float, ...] = DEFAULT_LAMBDA_SCA_NODES_M
    mie_g_nodes: tuple[float, ...] = (0.93,)
    n_photons: int = 1_000_000
    max_order: int = 6
    mc_band_px: int = 8
    path_max_m: float = 400.0
    seed: int = 0
    emission_shape: str = "linear"
    mc_phase: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if not self.cameras:
            raise ValueError("cameras: at least one camera is needed")
        if not self.focal_px > 0:
            raise ValueError(f"focal_px must be > 0, got {self.focal_px}")
        if self.n_bands < 8 or self.n_bands % self.mc_band_px:
            raise ValueError(
                f"n_bands must be >= 8 and a multiple of mc_band_px ({self.mc_band_px}), got {self.n_bands}"
            )
        nodes = self.lambda_sca_nodes_m
        if not nodes or any(not x > 0 for x in nodes) or list(nodes) != sorted(set(nodes)):
            raise ValueError(f"lambda_sca_nodes_m must be positive and increasing, got {nodes}")
        gs = self.mie_g_nodes
        if not gs or any(not -1 < g < 1 for g in gs) or list(gs) != sorted(set(gs)):
            raise ValueError(f"mie_g_nodes must lie in (-1, 1) and increase, got {gs}")
        if not 0 <= self.rayleigh_fraction <= 1:
            raise ValueError(f"rayleigh_fraction must lie in [0, 1], got {self.rayleigh_fraction}")
        if self.mc_phase is not None and not (-1 < self.mc_phase[0] < 1 and 0 <= self.mc_phase[1] <= 1):
            raise ValueError(f"mc_phase: (<cos theta> in (-1, 1), share in [0, 1]), got {self.mc_phase}")
        if not self.refractive_index >= 1:
            raise ValueError(f"refractive_index must be >= 1, got {self.refractive_index}")

    @classmethod
    def near_far(
        cls, distance_near_m: float, distance_far_m: float, focal_px: float, **kw: object
    ) -> TemplateSettings:
        """The two-camera layout of T-REX: near camera on the +z side, far camera on the -z side."""
        cams = (TemplateCamera("near", distance_near_m, 1), TemplateCamera("far", distance_far_m, -1))
        return cls(cameras=cams, focal_px=focal_px, **kw)  # type: ignore[arg-type]

    def _sites(self) -> tuple[CameraSite, ...]:
        return tuple(CameraSite(c.name, c.distance_m, c.side, self.focal_px) for c in self.cameras)

    def scene(self) -> TransportScene:
        """The bands of the templates: one pixel wide, then the outer bins."""
        return TransportScene(
            self._sites(),
            band_edges_px(self.n_bands, self.outer_px, self.n_outer),
            self.lem_radius_m,
            self.emission_shape,
        )

    def mc_scene(self) -> TransportScene:
        """The Monte Carlo's coarser bins: ``mc_band_px`` wide, then the same outer bins."""
        fine = np.asarray(band_edges_px(self.n_bands, self.outer_px, self.n_outer))
        coarse = np.concatenate([np.arange(0, self.n_bands + 1, self.mc_band_px), fine[self.n_bands + 1 :]])
        return TransportScene(
            self._sites(), tuple(float(e) for e in coarse), self.lem_radius_m, self.emission_shape
        )

    def geometry_description(self) -> dict[str, object]:
        """What the cached pieces depend on, besides their own node (and, for the MC, the seed)."""
        d = asdict(self)
        for k in ("lambda_sca_nodes_m", "mie_g_nodes", "seed", "n_photons", "max_order", "path_max_m"):
            d.pop(k)
        if d["emission_shape"] == "linear":
            d.pop("emission_shape")  # the caches made before the shape could change stay valid
        d.pop("mc_phase")  # the Monte Carlo pieces name it themselves (the first order does not need it)
        return d

    def mc_config(self) -> TransportConfig:
        return TransportConfig(
            n_photons=self.n_photons, max_order=self.max_order, path_max_m=self.path_max_m, direct_samples=0
        )


@dataclass(frozen=True)
class HaloTemplate:
    """Scattered-light radiance per camera, emission component and band, with its MC error.

    ``radiance`` and ``error`` have shape ``(camera, component, band)``;
    radiance is in units of the LEM's surface radiance toward the near
    camera. `total` applies an emission profile.
    """

    lambda_abs_m: float
    lambda_sca_m: float
    mie_g: float
    radiance: np.ndarray = field(repr=False)
    error: np.ndarray = field(repr=False)

    def total(self, profile: EmissionProfile) -> tuple[np.ndarray, np.ndarray]:
        """Radiance and error per camera and band for one emission profile."""
        w = profile.weights()
        value = np.einsum("k,ckb->cb", w, self.radiance)
        err = np.sqrt(np.einsum("k,ckb->cb", w * w, self.error**2))
        return value, err
