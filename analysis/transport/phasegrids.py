"""Template grids of several Rayleigh shares as one halo source over (⟨cos θ⟩, Rayleigh share).

A `TemplateGrid` holds one Rayleigh share and interpolates ⟨cos θ⟩ between
its nodes. `PhaseGridSet` puts grids that differ only in their Rayleigh
share side by side and interpolates linearly between them: the scattered
light is linear in the phase function, and the phase function is linear in
the share (p = (1 - f)·HG + f·Rayleigh), so at first order the blend is
exact; the higher orders are not linear in f, and the blend is as good as
the shares are close. It serves the χ² fit's phase map with the Monte Carlo
templates; a source smooth in all four parameters replaces it where one is
built.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from analysis.transport.template_settings import HaloTemplate, TemplateSettings
from analysis.transport.templates import TemplateGrid


@dataclass(frozen=True)
class PhaseGridSet:
    """Grids keyed by Rayleigh share (same geometry, nodes and ⟨cos θ⟩ nodes), blended linearly."""

    grids: Mapping[float, TemplateGrid] = field(repr=False)
    nominal_share: float

    def __post_init__(self) -> None:
        if not self.grids:
            raise ValueError("PhaseGridSet needs at least one grid")
        for share, grid in self.grids.items():
            if abs(grid.settings.rayleigh_fraction - share) > 1e-9:
                held = grid.settings.rayleigh_fraction
                raise ValueError(f"the grid keyed {share:g} holds Rayleigh share {held:g}")
        if self.nominal_share not in self.grids:
            raise ValueError(f"nominal share {self.nominal_share:g} is not among {sorted(self.grids)}")

    @property
    def shares(self) -> list[float]:
        return sorted(self.grids)

    @property
    def settings(self) -> TemplateSettings:
        """The nominal share's settings (geometry, bands: the same for all)."""
        return self.grids[self.nominal_share].settings

    @property
    def lambda_sca_range_m(self) -> tuple[float, float]:
        ranges = [g.lambda_sca_range_m for g in self.grids.values()]
        return max(r[0] for r in ranges), min(r[1] for r in ranges)

    @property
    def phase_ranges(self) -> tuple[tuple[float, float], tuple[float, float]]:
        gs = [g.phase_ranges[0] for g in self.grids.values()]
        shares = self.shares
        return (max(r[0] for r in gs), min(r[1] for r in gs)), (shares[0], shares[-1])

    def halo(
        self,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None = None,
        rayleigh_share: float | None = None,
    ) -> HaloTemplate:
        f = self.nominal_share if rayleigh_share is None else float(rayleigh_share)
        shares = self.shares
        if not shares[0] - 1e-9 <= f <= shares[-1] + 1e-9:
            raise ValueError(f"rayleigh_share {f:g} outside the grids' shares {shares[0]:g}-{shares[-1]:g}")
        j = int(np.clip(np.searchsorted(shares, f) - 1, 0, max(len(shares) - 2, 0)))
        lo = shares[j]
        a = self.grids[lo].halo(lambda_abs_m, lambda_sca_m, mie_g)
        if len(shares) == 1:
            return a
        hi = shares[j + 1]
        t = float(np.clip((f - lo) / (hi - lo), 0.0, 1.0))
        b = self.grids[hi].halo(lambda_abs_m, lambda_sca_m, mie_g)
        return HaloTemplate(
            lambda_abs_m,
            lambda_sca_m,
            a.mie_g,
            (1 - t) * a.radiance + t * b.radiance,
            np.sqrt((1 - t) ** 2 * a.error**2 + t**2 * b.error**2),
        )
