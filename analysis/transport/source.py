"""What the χ² fit needs of its templates: a halo at any water it may visit (`HaloSource`).

`analysis.transport.templates.TemplateGrid` (Monte Carlo nodes),
`analysis.transport.phasegrids.PhaseGridSet` and
`analysis.transport.smooth.SmoothTemplates` all serve it.
"""

from __future__ import annotations

from typing import Protocol

from analysis.transport.template_settings import HaloTemplate, TemplateSettings


class HaloSource(Protocol):
    """Templates the fit evaluates: their geometry, the scattering lengths served, a halo at a water."""

    @property
    def settings(self) -> TemplateSettings: ...

    @property
    def lambda_sca_range_m(self) -> tuple[float, float]: ...

    def halo(
        self,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None = None,
        rayleigh_share: float | None = None,
    ) -> HaloTemplate: ...
