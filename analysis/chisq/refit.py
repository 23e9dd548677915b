"""Refits of one wavelength's data from the nominal minimum with some inputs replaced (the budget's).

Each refit starts where the nominal fit ended and reports (λ_abs, λ_sca,
λ_att, χ²) at its minimum, and how far it had to move the floated
calibrations there (the largest |nuisance pull|). Used by
`analysis.chisq.systematics`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from analysis.chisq.data import SettingProfiles
from analysis.chisq.results import NUISANCES, ChiSquareFit
from analysis.chisq.wavelength import make_objective
from analysis.transport.source import HaloSource


class Refitter:
    """Refits of one wavelength's data from the nominal minimum, with some inputs replaced."""

    def __init__(self, fit: ChiSquareFit, settings: Sequence[SettingProfiles], grid: HaloSource) -> None:
        self.settings = settings
        self.inputs: dict[str, object] = {
            "grid": grid,
            "geometry": fit.geometry,
            "ratio": fit.emission_ratio,
            "config": fit.config,
        }
        self.start = np.log([fit.lambda_abs_m, fit.lambda_sca_m])
        # A length the fit only bounds gets no shift: its minimum sits on the grid's edge.
        self.mask = np.array(
            [1.0 if fit.lambda_abs.measured else np.nan, 1.0 if fit.lambda_sca.measured else np.nan, 1.0, 1.0]
        )
        # A fit that measured the phase function is refitted at the phase function it found.
        self.phase = (fit.mie_g, fit.rayleigh_share) if fit.phase is not None else None
        self.n_refits = 0
        self.edge_hits = 0
        # Only a fit that strained a calibration asks how far each refit moves them (`max_pull`).
        self.track_pulls = bool(fit.strained_nuisances)
        self._refs: dict[str, tuple[np.ndarray, float]] = {}
        self._disks: dict = {}  # type: ignore[type-arg]

    def __call__(self, **replaced: object) -> np.ndarray:
        """(λ_abs, λ_sca, λ_att, χ²) of the minimum with ``replaced`` inputs, found from the nominal one."""
        return self._refit(**replaced)[0]

    def _refit(self, **replaced: object) -> tuple[np.ndarray, float]:
        """`__call__`'s values and the largest |nuisance pull| at that minimum (0 unless
        ``track_pulls``)."""
        kw = {**self.inputs, **replaced}
        obj = make_objective(
            self.settings,
            kw["grid"],  # type: ignore[arg-type]
            kw["geometry"],  # type: ignore[arg-type]
            kw["ratio"],  # type: ignore[arg-type]
            kw["config"],  # type: ignore[arg-type]
            self._disks,
        )
        if self.phase is not None:
            obj.prob.set_phase(*self.phase)
        p = obj.minimise(self.start, near=True)
        best = np.exp(p)
        self.n_refits += 1
        if obj.on_edge(float(p[1]), 1) or obj.on_edge(float(p[0]), 0):
            self.edge_hits += 1
        pull = 0.0
        if self.track_pulls:
            prob = obj.prob
            shifts = np.asarray(prob.chi2(float(best[0]), float(best[1]), detail=True)[1]["shifts"])
            sigma = np.asarray(prob.prior_sigma, dtype=float)
            calibrations = (k for k in prob.active if k < len(NUISANCES) and sigma[k] > 0)
            pull = max((abs(shifts[k] / sigma[k]) for k in calibrations), default=0.0)
        return np.array([best[0], best[1], 1.0 / (1.0 / best[0] + 1.0 / best[1]), obj(p)]), pull

    def _memo(self, **replaced: object) -> tuple[np.ndarray, float]:
        key = repr(sorted(replaced.items()))
        if key not in self._refs:
            self._refs[key] = self._refit(**replaced)
        return self._refs[key]

    def reference(self, **replaced: object) -> np.ndarray:
        return self._memo(**replaced)[0]

    def max_pull(self, **replaced: object) -> float:
        """The largest |nuisance pull| (σ of its prior) at the reference refit with ``replaced``
        (0 unless ``track_pulls``: the nominal fit strained a calibration)."""
        return self._memo(**replaced)[1]

    def shifts(
        self, cases: Sequence[tuple[str, Mapping[str, object]]], reference: Mapping[str, object] | None = None
    ) -> np.ndarray:
        """(case, [Δλ_abs, Δλ_sca, Δλ_att, Δχ²]) against the reference refit (NaN for a bounded length)."""
        ref = self.reference(**(reference or {}))
        # Every case goes through the same memo: a case equal to the reference is not refitted.
        return np.array([(self.reference(**kw) - ref) * self.mask for _, kw in cases])
