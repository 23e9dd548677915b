"""Variations of the smooth templates for the systematic budget: the small-angle orders scaled.

The orders >= 2 of `SmoothTemplates` come from the small-angle approximation,
whose stated accuracy (`HIGHER_ORDER_REL_ERR`) is a relative error of the
multiply scattered light as a whole more than of single bands: the budget
refits with those orders scaled up and down by it, and the shift of the
lengths is that line's error.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from analysis.transport.smooth import FIRST_ORDER_REL_ERR, HIGHER_ORDER_REL_ERR, SmoothTemplates
from analysis.transport.template_settings import HaloTemplate, TemplateSettings


@dataclass(frozen=True)
class ScaledHigherOrders:
    """`SmoothTemplates` with its orders >= 2 multiplied by ``factor``."""

    base: SmoothTemplates = field(repr=False)
    factor: float

    @property
    def settings(self) -> TemplateSettings:
        return self.base.settings

    @property
    def lambda_sca_range_m(self) -> tuple[float, float]:
        return self.base.lambda_sca_range_m

    @property
    def mie_g_range(self) -> tuple[float, float]:
        return self.base.mie_g_range

    @property
    def rayleigh_share_range(self) -> tuple[float, float]:
        return self.base.rayleigh_share_range

    def halo(
        self,
        lambda_abs_m: float,
        lambda_sca_m: float,
        mie_g: float | None = None,
        rayleigh_share: float | None = None,
    ) -> HaloTemplate:
        first, higher = self.base.parts(lambda_abs_m, lambda_sca_m, mie_g, rayleigh_share)
        higher = higher * self.factor
        g = self.base.settings.mie_g_nodes[0] if mie_g is None else float(mie_g)
        err = np.hypot(FIRST_ORDER_REL_ERR * first, HIGHER_ORDER_REL_ERR * higher)
        return HaloTemplate(lambda_abs_m, lambda_sca_m, g, first + higher, err)


def higher_order_variants(base: SmoothTemplates) -> dict[str, ScaledHigherOrders]:
    """The budget's two cases: the small-angle orders up and down by their stated accuracy."""
    return {
        f"higher={sign:+d}": ScaledHigherOrders(base, 1.0 + sign * HIGHER_ORDER_REL_ERR) for sign in (-1, 1)
    }
