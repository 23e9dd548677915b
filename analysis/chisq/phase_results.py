"""What the phase-function part of the χ² fit is configured with and returns (`analysis.chisq.phase`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FIXED = "fixed"
#: Phase cases of a fit.
PHASE_MEASURED = "measured"
PHASE_LIMIT = "limit"
PHASE_DEGENERATE = "degenerate"
PHASE_FIXED = "fixed"


@dataclass(frozen=True)
class PhaseConfig:
    """The phase function's range and map: Mie ⟨cos θ⟩ and Rayleigh share (clipped to the templates').

    The defaults span what ocean water holds (the particles' ⟨cos θ⟩
    0.85-0.97, a Rayleigh share of 0.05-0.35 from turbid to clear blue water)
    with a margin.

    ``model_dchi2`` is the map's tolerance for what the templates cannot yet
    tell apart, in Δχ²/s²: the intervals of the phase function and the
    lengths' envelopes are read from max(0, Δχ²/s² − model_dchi2), the best
    point from the map itself. Measured on frames of an independent
    transport (Mitsuba 3, HG 0.96 + 5 % and 0.87 + 30 % Rayleigh,
    docs/transport.md): the map's minimum sat 10-20 above the truth's own
    phase function, whose lengths were right; 0 trusts the templates fully.
    """

    mie_g_range: tuple[float, float] = (0.84, 0.98)
    rayleigh_range: tuple[float, float] = (0.0, 0.40)
    mie_g_points: int = 8
    rayleigh_points: int = 5
    fine_points: int = 141
    model_dchi2: float = 20.0

    def __post_init__(self) -> None:
        if not -1 < self.mie_g_range[0] < self.mie_g_range[1] < 1:
            raise ValueError(f"mie_g_range must increase inside (-1, 1), got {self.mie_g_range}")
        if not 0 <= self.rayleigh_range[0] < self.rayleigh_range[1] <= 1:
            raise ValueError(f"rayleigh_range must increase inside [0, 1], got {self.rayleigh_range}")
        if not self.model_dchi2 >= 0:
            raise ValueError(f"model_dchi2 must be >= 0, got {self.model_dchi2}")
        if self.mie_g_points < 4 or self.rayleigh_points < 2:
            raise ValueError("mie_g_points must be >= 4 and rayleigh_points >= 2")


@dataclass(frozen=True)
class PhaseParameter:
    """One phase-function parameter: a value with its (asymmetric) 68 % interval, a limit, or nothing."""

    name: str
    status: str  # MEASURED, LOWER_LIMIT, UPPER_LIMIT, UNCONSTRAINED or FIXED
    value: float | None
    err: float | None
    interval: tuple[float, float] | None
    limit: float | None = None
    cl: float | None = None

    def to_dict(self) -> dict[str, object]:
        return {
            "status": self.status,
            "value": self.value,
            "err": self.err,
            "interval": list(self.interval) if self.interval else None,
            "limit": self.limit,
            "cl": self.cl,
        }


@dataclass(frozen=True)
class PhaseMap:
    """χ² profiled over everything else at each (g, f) node, and where each node's lengths went."""

    mie_g: np.ndarray = field(repr=False)  # (n_g,)
    rayleigh_share: np.ndarray = field(repr=False)  # (n_f,)
    chi2: np.ndarray = field(repr=False)  # (n_f, n_g)
    ln_lambda: np.ndarray = field(repr=False)  # (2, n_f, n_g): ln λ_abs, ln λ_sca at each node's minimum
    ndof: int = 0  # of the fit at each node (for its error scale); 0: unknown
    joint: tuple[int, ...] = ()  # other wavelengths [nm] whose profile in ⟨cos θ⟩ is added (`combine_maps`)

    @property
    def scale(self) -> float:
        """√(χ²/ndof) at the map's minimum, at least 1 (1 when ndof is unknown)."""
        if self.ndof <= 0:
            return 1.0
        return max(1.0, float(np.sqrt(np.nanmin(self.chi2) / self.ndof)))


@dataclass(frozen=True)
class PhaseFit:
    """The phase function the fit measured, and how it widens the lengths.

    ``case``: `PHASE_MEASURED` (⟨cos θ⟩'s interval closed inside the range),
    `PHASE_LIMIT` (open on one side: a limit), `PHASE_DEGENERATE` (open on
    both: the data do not tell ⟨cos θ⟩ from λ_sca over the range, whose
    whole span then sits in the lengths' errors). ``delta_chi2`` is the map's
    Δχ²/s² (rows: Rayleigh shares). ``lambda_envelope_m``: per length (λ_abs,
    λ_sca) the 68 % interval over all phase functions the data allow, None
    where it reaches the range's end. ``corr_lambda_sca`` the correlation of
    (g, f) with ln λ_sca over the data's posterior on the map.
    """

    case: str
    case_text: str
    mie_g: PhaseParameter
    rayleigh_share: PhaseParameter
    mean_cos_theta: PhaseParameter
    best: tuple[float, float]
    corr_lambda_sca: tuple[float, float]
    map: PhaseMap = field(repr=False)
    delta_chi2: np.ndarray = field(repr=False)
    lambda_envelope_m: tuple[tuple[float, float] | None, tuple[float, float] | None]
