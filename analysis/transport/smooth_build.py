"""Building `SmoothTemplates`: the first-order and small-angle tables per ⟨cos θ⟩ node, cached.

Each node's pieces are cached on their own (`TemplateCache`, content-hashed
``.npz``), so an interrupted build keeps what it finished and another geometry
reuses the phase functions' cap tables. The pieces are deterministic: the
same settings give the same tables on any machine and worker count.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np

from analysis.transport.cache import TemplateCache, cache_key
from analysis.transport.single import first_order_lines
from analysis.transport.smallangle import order_kernels
from analysis.transport.smooth import SmoothGrid, SmoothTemplates, first_order_k_table
from analysis.transport.template_settings import TemplateSettings
from analysis.transport.templates import cached_cap_table

#: Bumped when the tables' content changes meaning.
SMOOTH_VERSION = 1


def smooth_geometry(settings: TemplateSettings) -> dict[str, object]:
    """What the tables depend on: the cameras, bands, LEM and emission split (not the water)."""
    return {
        "cameras": [[c.name, c.distance_m, c.side] for c in settings.cameras],
        "focal_px": settings.focal_px,
        "n_bands": settings.n_bands,
        "outer_px": settings.outer_px,
        "n_outer": settings.n_outer,
        "lem_radius_m": settings.lem_radius_m,
        "emission_shape": settings.emission_shape,
        "path_max_m": settings.path_max_m,
        "version": SMOOTH_VERSION,
    }


@dataclass(frozen=True)
class _Job:
    """One table to compute: ``kind`` "first" (a phase function's first order) or "orders"."""

    kind: str
    settings: TemplateSettings
    grid: SmoothGrid
    mie_g: float  # unused for Rayleigh's first order
    rayleigh: bool
    cache: TemplateCache

    def description(self) -> dict[str, object]:
        d: dict[str, object] = {"geometry": smooth_geometry(self.settings), "kind": self.kind}
        if self.kind == "first":
            d["phase"] = "rayleigh" if self.rayleigh else round(self.mie_g, 12)
            d["k_nodes"] = [round(float(k), 12) for k in self.grid.k_nodes()]
        else:
            d["mie_g"] = round(self.mie_g, 12)
            d["n_orders"] = self.grid.n_orders
        return d

    def key(self) -> str:
        return cache_key(f"smooth-{self.kind}", self.description())


def _compute(job: _Job) -> dict[str, np.ndarray]:
    s = job.settings
    dist = np.array([c.distance_m for c in s.cameras])
    if job.kind == "first":
        g, f = (0.0, 1.0) if job.rayleigh else (job.mie_g, 0.0)
        table = cached_cap_table(s.lem_radius_m, g, f, s.path_max_m, job.cache)
        lines = first_order_lines(s.scene(), table, path_max_m=s.path_max_m)
        return {"table": first_order_k_table(lines, dist, s.lem_radius_m, job.grid.k_nodes())}
    scene = s.scene()
    edges = np.stack([scene.psi_edges_rad(c) for c in range(len(s.cameras))])
    alpha = np.arcsin(s.lem_radius_m / dist)
    return {"table": order_kernels(edges, alpha, np.array([job.mie_g]), job.grid.n_orders)[0]}


def build_smooth_templates(
    settings: TemplateSettings,
    cache: TemplateCache | None = None,
    executor: Executor | None = None,
    progress: Callable[[int, int], None] | None = None,
    grid: SmoothGrid | None = None,
) -> SmoothTemplates:
    """Load the tables of ``settings``' geometry from the cache, computing the missing ones.

    Per ⟨cos θ⟩ node of ``grid`` (default `SmoothGrid()`) one first-order table and one
    small-angle table, plus Rayleigh's first order; computed on ``executor`` if
    given (the caller owns it), else here one after the other.
    """
    cache = cache or TemplateCache()
    grid = grid or SmoothGrid()
    gs = [float(1.0 - math.exp(x)) for x in grid.x_nodes()]
    jobs = [_Job("first", settings, grid, g, False, cache) for g in gs]
    jobs.append(_Job("first", settings, grid, 0.0, True, cache))
    jobs += [_Job("orders", settings, grid, g, False, cache) for g in gs]
    found: dict[int, np.ndarray] = {}
    todo: list[int] = []
    for i, job in enumerate(jobs):
        arr = cache.load(job.key())
        if arr is None:
            todo.append(i)
        else:
            found[i] = arr["table"]
    done = len(found)
    if progress:
        progress(done, len(jobs))
    todo_jobs = [jobs[i] for i in todo]
    results = (
        executor.map(_compute, todo_jobs)
        if executor is not None and len(todo) > 1
        else map(_compute, todo_jobs)
    )
    for i, arrays in zip(todo, results, strict=True):
        cache.save(jobs[i].key(), arrays, jobs[i].description())
        found[i] = arrays["table"]
        done += 1
        if progress:
            progress(done, len(jobs))
    n_g = len(gs)
    return SmoothTemplates(
        settings,
        grid,
        np.stack([found[i] for i in range(n_g)]),
        found[n_g],
        np.stack([found[n_g + 1 + i] for i in range(n_g)]),
    )
