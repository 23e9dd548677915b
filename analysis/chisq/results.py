"""What the χ² fit returns: its configuration, the estimates (values or limits), nuisances, budget."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from analysis.attenuation import EmissionRatio, Geometry
from analysis.chisq.phase_results import PhaseConfig, PhaseFit
from analysis.transport.templates import TemplateSettings

#: Δχ² of a one-parameter 68 % interval and of the joint 2-D 68 % and 95 % regions.
DCHI2_1D = 1.0
DCHI2_2D_68 = 2.30
DCHI2_2D_95 = 6.18
#: Δχ² of a one-sided 95 % confidence limit on one parameter (1.645²).
DCHI2_LIMIT_95 = 2.706
#: A fit's λ_att that differs from the I_center λ_att by more than this many σ is flagged.
ATT_CHECK_FLAG_SIGMA = 3.0
#: A floated nuisance (I0'/I0, a distance, the PSF, ...) moved further than this many σ of its prior
#: says the frames do not follow the model with the calibration as given: the fit is flagged.
NUISANCE_FLAG_SIGMA = 3.0


@dataclass(frozen=True)
class FitConfig:
    """Choices of the χ² fit.

    ``psf_sigma_px`` ± ``psf_sigma_err_px`` is the Gaussian PSF (defocus
    plus the sub-pixel spread of stacking); ``focal_rel_err`` the relative
    uncertainty of the image scale; ``halo_scale_err`` that of the templates'
    overall halo level (their accuracy: the quadrature's, the Monte Carlo's
    normalisation), common to all bands; ``halo_shape_err`` that of the
    halo's shape per camera: the halo is multiplied by 1 + Σ ε_j B_j(ln ρ),
    B_j hat functions ``halo_shape_step`` apart in ln ρ from the disk's edge
    to the last band (the halo under the disk takes the edge's), each ε_j a
    nuisance with that prior width. A template off by a percent over a
    tenth of the radius (or the truth of a test, tabulated by another
    engine with its own noise) then costs χ² once, as it should, instead of
    once per band, as independent per-band errors would, which average down
    and let the shape's misfit pass for another water or phase function;
    ``halo_disk_err`` that of the halo under the disk per camera (on its
    own: it sits under the direct light, and sets the disks' brightness; 0, off, by default: on
    Mitsuba's turbid frames with Monte Carlo templates ±5 % moved λ_att by +1.8 % and did not bring the
    phase fit on the off-nominal tables nearer their truth); ``lambda_sca_sys_rel`` the relative
    systematic error quoted on λ_sca for the templates' accuracy (the halo's
    radial shape fixes λ_sca to ~0.1 % statistically, finer than the first
    order's quadrature is exact near the LEM's limb, 0.1-0.4 %);
    ``model_rel_err`` a relative uncertainty
    added to every model bin (the LEM's and the optics' departures from the
    ideal model); bands with fewer than ``min_band_pixels`` pixels are left
    out, and so are bands whose 8-bit rounding bias could exceed
    ``max_quantisation_bias`` times their statistical error
    (`quantisation_bias_gray`: the faint halo at low gain).
    ``template_errors`` adds the templates' Monte Carlo errors to σ_T (held
    at their values for the current best water); switch it off when the data
    were simulated from the same template grid (a shared Monte Carlo sample
    is no independent error, and counting it de-weights the halo). ``mie_g``
    (⟨cos θ⟩) is held at this value (None: the templates' first node), unless
    ``phase`` is given and the templates span a range of phase functions: then
    Mie ⟨cos θ⟩ and the Rayleigh share are fitted (`analysis.chisq.phase`).
    ``edge_sigmas_px``: the disk's edge per setting and camera is the working
    PSF's disk plus these blurs' disks in free proportions (flux-conserving:
    light moves across the edge only), so that frames whose blur differs
    from frame to frame (sway, focus) do not steer the fit; empty: one PSF
    width for all, a nuisance with prior ``psf_sigma_err_px``.
    ``contour_points`` per axis of the Δχ² map.
    """

    psf_sigma_px: float = 1.2
    psf_sigma_err_px: float = 0.3
    edge_sigmas_px: tuple[float, ...] = (0.6, 2.0, 3.2, 4.5)
    focal_rel_err: float = 0.003
    halo_scale_err: float = 0.005
    halo_shape_err: float = 0.01
    halo_disk_err: float = 0.0
    halo_shape_step: float = 0.06
    lambda_sca_sys_rel: float = 0.005
    model_rel_err: float = 0.002
    min_band_pixels: int = 16
    max_quantisation_bias: float = 0.1
    template_errors: bool = True
    mie_g: float | None = None
    lambda_abs_range_m: tuple[float, float] = (2.0, 2000.0)
    contour_points: int = 25
    phase: PhaseConfig | None = None

    def __post_init__(self) -> None:
        if not self.psf_sigma_px > 0 or self.psf_sigma_err_px < 0:
            raise ValueError(f"psf_sigma_px must be > 0 and psf_sigma_err_px >= 0, got {self.psf_sigma_px}")
        errs = (
            self.focal_rel_err,
            self.model_rel_err,
            self.halo_scale_err,
            self.halo_shape_err,
            self.halo_disk_err,
        )
        if min(*errs, self.lambda_sca_sys_rel) < 0:
            raise ValueError(
                "focal_rel_err, halo_scale_err, halo_shape_err, halo_disk_err, lambda_sca_sys_rel and "
                "model_rel_err must be >= 0"
            )
        if not self.halo_shape_step > 0:
            raise ValueError(f"halo_shape_step must be > 0, got {self.halo_shape_step}")
        if self.contour_points < 5:
            raise ValueError(f"contour_points must be >= 5, got {self.contour_points}")


@dataclass(frozen=True)
class Nuisance:
    """A fitted nuisance parameter: its shift from nominal, prior width and pull (shift/width)."""

    name: str
    unit: str
    shift: float
    sigma: float

    @property
    def pull(self) -> float:
        return self.shift / self.sigma if self.sigma > 0 else 0.0


@dataclass(frozen=True)
class ContourMap:
    """Δχ² (profiled over everything else) on a grid of λ_abs × λ_sca (both log-spaced)."""

    lambda_abs_m: np.ndarray = field(repr=False)
    lambda_sca_m: np.ndarray = field(repr=False)
    delta_chi2: np.ndarray = field(repr=False)  # shape (len(lambda_sca_m), len(lambda_abs_m))


@dataclass(frozen=True)
class SettingModel:
    """Data and best-fit model of one setting, normalised (for plots and residuals)."""

    exposure_s: float
    gain_db: float
    radius_px: np.ndarray = field(repr=False)
    data: np.ndarray = field(repr=False)  # (2, n) near, far
    error: np.ndarray = field(repr=False)
    model: np.ndarray = field(repr=False)
    halo: np.ndarray = field(repr=False)
    used: np.ndarray = field(repr=False)


MEASURED = "measured"
LOWER_LIMIT = "lower_limit"
UPPER_LIMIT = "upper_limit"
UNCONSTRAINED = "unconstrained"


@dataclass(frozen=True)
class Estimate:
    """What the fit says about one length: a value with its error, a one-sided limit, or nothing.

    ``status`` is `MEASURED` (``value_m`` ± ``err_m``, the 68 % interval
    ``interval_m`` closed on both sides inside the allowed range),
    `LOWER_LIMIT` (the χ² keeps falling toward the range's upper edge:
    the length exceeds ``limit_m`` at confidence ``cl``), `UPPER_LIMIT` (the
    mirror image at the lower edge) or `UNCONSTRAINED` (open on both
    sides). A limit never carries a value: the minimum's position on an
    edge is the grid's, not the water's. Errors are those of the fit (data
    plus the profiled nuisances), scaled by the fit's error scale.
    """

    name: str
    status: str
    value_m: float | None
    err_m: float | None
    interval_m: tuple[float, float] | None
    limit_m: float | None = None
    cl: float | None = None

    @property
    def measured(self) -> bool:
        return self.status == MEASURED

    def moved(self, shift_m: float) -> Estimate:
        """A measured value and its interval moved by ``shift_m`` (a limit or nothing stays as it is)."""
        if not self.measured or self.value_m is None or shift_m == 0.0:
            return self
        iv = self.interval_m
        moved = None if iv is None else (iv[0] + shift_m, iv[1] + shift_m)
        return replace(self, value_m=self.value_m + shift_m, interval_m=moved)

    def text(self, symbol: str, digits: int = 2, sys_err_m: float | None = None) -> str:
        """``"λ_abs = 39.20 ± 1.10 m"``, ``"λ_abs > 180 m (95 % CL)"`` or ``"λ_abs unconstrained"``."""
        if self.status == MEASURED:
            sys_txt = f" ± {sys_err_m:.{digits}f} (sys)" if sys_err_m is not None else ""
            return f"{symbol} = {self.value_m:.{digits}f} ± {self.err_m:.{digits}f}{sys_txt} m"
        if self.status in (LOWER_LIMIT, UPPER_LIMIT):
            sign = ">" if self.status == LOWER_LIMIT else "<"
            return f"{symbol} {sign} {self.limit_m:.3g} m ({100 * (self.cl or 0.95):.0f} % CL)"
        return f"{symbol} unconstrained"


def cases_text(cases: tuple[str, ...] | list[str], most: int = 6) -> str:
    """A budget line's cases for a table: all of them, or the first and last and how many."""
    if len(cases) <= most:
        return ", ".join(cases)
    return f"{cases[0]} … {cases[-1]} ({len(cases)} refits)"


def sys_text(up_m: float, down_m: float, digits: int = 2) -> str:
    """A systematic error as text: "± 0.30" when both sides agree at ``digits``, else "+4.10/−0.90"
    ("—" for a length the fit only bounds)."""
    if not (math.isfinite(up_m) and math.isfinite(down_m)):
        return "—"
    u, d = f"{up_m:.{digits}f}", f"{down_m:.{digits}f}"
    return f"± {u}" if u == d else f"+{u}/−{d}"


def largest_shift(values: tuple[float, ...]) -> float:
    """The largest finite |shift| of a budget item (NaN when none is finite)."""
    finite = [abs(v) for v in values if math.isfinite(v)]
    return max(finite) if finite else float("nan")


@dataclass(frozen=True)
class SystematicShift:
    """One line of the systematic budget: the shifts of λ_abs, λ_sca and λ_att per variation case.

    ``cases`` names the variations (e.g. ``"0.88"``, ``"0.96"``) and
    ``delta_chi2`` each case's χ² minimum less the reference's (positive: the
    data prefer the nominal). ``errors_m`` is the item's error on (λ_abs,
    λ_sca, λ_att): the largest |shift| unless ``note`` says how the data
    narrowed it (`analysis.chisq.systematics`). ``errors_up_m`` and
    ``errors_down_m``, where given, split that error by the shifts' sign:
    how far the lengths may lie above and below the value (for the phase
    function, whose refits move λ_abs up much further than down); without
    them the error is symmetric. A length the fit only bounds gets NaN.
    ``profiled`` items are nuisances the fit already floats with a
    prior (their error is inside the fit error): they are listed as impacts
    and not added to the systematic error again.
    """

    name: str
    label: str
    cases: tuple[str, ...]
    lambda_abs_shifts_m: tuple[float, ...]
    lambda_sca_shifts_m: tuple[float, ...]
    lambda_att_shifts_m: tuple[float, ...]
    delta_chi2: tuple[float, ...]
    errors_m: tuple[float, float, float]
    profiled: bool = False
    note: str = ""
    errors_up_m: tuple[float, float, float] | None = None
    errors_down_m: tuple[float, float, float] | None = None

    @property
    def up_m(self) -> tuple[float, float, float]:
        """The error upward on (λ_abs, λ_sca, λ_att): how far above the value the lengths may lie."""
        return self.errors_m if self.errors_up_m is None else self.errors_up_m

    @property
    def down_m(self) -> tuple[float, float, float]:
        """The error downward on (λ_abs, λ_sca, λ_att)."""
        return self.errors_m if self.errors_down_m is None else self.errors_down_m

    @property
    def lambda_abs_m(self) -> float:
        return self.errors_m[0]

    @property
    def lambda_sca_m(self) -> float:
        return self.errors_m[1]

    @property
    def lambda_att_m(self) -> float:
        return self.errors_m[2]


def _quadrature(vals: list[float]) -> float:
    if not vals or any(math.isnan(v) for v in vals):
        return float("nan")
    return math.sqrt(sum(v * v for v in vals))


@dataclass(frozen=True)
class SystematicBudget:
    """The shifts of what the fit holds fixed, one at a time, and their sum in quadrature.

    The sums leave out the ``profiled`` items (already in the fit error);
    NaN when the length is only bounded. `sys_up_m` and `sys_down_m` sum
    each side separately (a symmetric item counts on both), for a length
    ``k`` (0 λ_abs, 1 λ_sca, 2 λ_att).
    """

    items: tuple[SystematicShift, ...]
    seconds: float
    #: The limits (λ_abs, λ_sca) keep once the phase function is varied: for a length the nominal fit
    #: only bounds, the loosest bound any phase refit reaches (None: no limit, or none looser).
    limits_m: tuple[float | None, float | None] = (None, None)
    #: How far the values quoted move from the nominal templates' minimum (λ_abs, λ_sca, λ_att): to
    #: the mean over the nominal and the template samples (the ``template_sample`` line), whose
    #: error that line carries.
    sample_move_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    #: A phase function the data allow (its refit within Δχ²/s² ≤ 2.30 of the nominal) at which every
    #: floated calibration stays within `NUISANCE_FLAG_SIGMA`: (case "⟨cos θ⟩/Rayleigh share",
    #: Δχ²/s², the largest |nuisance pull| there). None: no phase refit does that, or none was made.
    #: Nuisances strained at the nominal phase function but not there are the phase function's doing
    #: (the budget's phase line covers it), not a calibration's.
    phase_relief: tuple[str, float, float] | None = None

    def _sum(self, attr: str) -> float:
        return _quadrature([getattr(i, attr) for i in self.items if not i.profiled])

    def sys_up_m(self, k: int) -> float:
        return _quadrature([i.up_m[k] for i in self.items if not i.profiled])

    def sys_down_m(self, k: int) -> float:
        return _quadrature([i.down_m[k] for i in self.items if not i.profiled])

    @property
    def lambda_abs_sys_m(self) -> float:
        return self._sum("lambda_abs_m")

    @property
    def lambda_sca_sys_m(self) -> float:
        return self._sum("lambda_sca_m")

    @property
    def lambda_att_sys_m(self) -> float:
        return self._sum("lambda_att_m")


@dataclass(frozen=True)
class ChiSquareFit:
    """λ_abs and λ_sca of one wavelength with errors or limits, and everything that led to them.

    ``lambda_abs``/``lambda_sca`` are the results to quote (`Estimate`: a
    value or a one-sided limit). ``lambda_abs_m``/``lambda_sca_m`` are the
    χ² minimum's position (on an edge when that parameter is only bounded);
    ``*_err_m`` the mean half-width of the Δχ² = error_scale² crossings,
    ``*_interval_m`` those crossings. ``error_scale`` is √(χ²/ndof) when
    that exceeds 1, else 1: the fit errors, intervals, covariance and the
    Δχ² map are all scaled by it (the PDG's recipe for a model that does
    not describe the data within their errors). ``lambda_sca_sys_err_m`` /
    ``lambda_abs_sys_err_m`` are the systematic errors: the budget's sum in
    quadrature when ``systematics`` is given (`with_budget`), else only the
    templates' accuracy on λ_sca (`FitConfig.lambda_sca_sys_rel`). ``lambda_att_m``
    follows from 1/λ_att = 1/λ_abs + 1/λ_sca with its error from the local
    curvature of χ². ``at_edge`` names a parameter whose 68 % interval
    reaches the edge of the allowed range.
    """

    wavelength_nm: int
    lambda_abs_m: float
    lambda_abs_err_m: float
    lambda_abs_interval_m: tuple[float, float]
    lambda_sca_m: float
    lambda_sca_err_m: float
    lambda_sca_interval_m: tuple[float, float]
    lambda_sca_sys_err_m: float
    lambda_att_m: float
    lambda_att_err_m: float
    correlation: float
    chi2: float
    ndof: int
    mie_g: float
    nuisances: tuple[Nuisance, ...]
    at_edge: tuple[str, ...]
    contour: ContourMap = field(repr=False)
    settings: tuple[SettingModel, ...] = field(repr=False)
    geometry: Geometry
    emission_ratio: EmissionRatio
    config: FitConfig
    focal_px: float
    templates: TemplateSettings
    n_evaluations: int
    lambda_abs: Estimate
    lambda_sca: Estimate
    error_scale: float = 1.0
    lambda_abs_sys_err_m: float = 0.0
    lambda_att_sys_err_m: float = 0.0
    systematics: SystematicBudget | None = None
    rayleigh_share: float = 0.17
    phase: PhaseFit | None = None

    @property
    def lambda_sca_total_err_m(self) -> float:
        return math.hypot(self.lambda_sca_err_m, self.lambda_sca_sys_err_m)

    @property
    def lambda_abs_total_err_m(self) -> float:
        return math.hypot(self.lambda_abs_err_m, self.lambda_abs_sys_err_m)

    @property
    def chi2_ndof(self) -> float:
        return self.chi2 / self.ndof if self.ndof > 0 else float("nan")

    @property
    def strained_nuisances(self) -> tuple[Nuisance, ...]:
        """The nuisances the fit moved beyond `NUISANCE_FLAG_SIGMA` of their priors, worst first."""
        strained = [n for n in self.nuisances if abs(n.pull) > NUISANCE_FLAG_SIGMA]
        return tuple(sorted(strained, key=lambda n: -abs(n.pull)))

    @property
    def phase_relief(self) -> tuple[str, float, float] | None:
        """`SystematicBudget.phase_relief` of the budget attached (None without one)."""
        return None if self.systematics is None else self.systematics.phase_relief

    @property
    def calibration_flagged(self) -> bool:
        """Nuisances strained beyond `NUISANCE_FLAG_SIGMA` that no phase function the data allow
        relieves: the frames do not follow the model with the calibration as given."""
        return bool(self.strained_nuisances) and self.phase_relief is None

    def with_budget(self, budget: SystematicBudget) -> ChiSquareFit:
        """This fit with the systematic budget attached and its sums as the systematic errors.

        A limit is loosened to the budget's (`SystematicBudget.limits_m`): "λ_abs > 281 m" at the
        nominal phase function becomes "> 24 m" when a refit at another ⟨cos θ⟩ reaches 24 m.
        """
        ab, sc = self.lambda_abs, self.lambda_sca
        if budget.limits_m[0] is not None and ab.status in (LOWER_LIMIT, UPPER_LIMIT):
            ab = replace(ab, limit_m=budget.limits_m[0])
        if budget.limits_m[1] is not None and sc.status in (LOWER_LIMIT, UPPER_LIMIT):
            sc = replace(sc, limit_m=budget.limits_m[1])
        ab, sc = ab.moved(budget.sample_move_m[0]), sc.moved(budget.sample_move_m[1])
        return replace(
            self,
            systematics=budget,
            lambda_abs=ab,
            lambda_sca=sc,
            lambda_att_m=self.lambda_att_m + budget.sample_move_m[2],
            lambda_abs_sys_err_m=budget.lambda_abs_sys_m,
            lambda_sca_sys_err_m=budget.lambda_sca_sys_m,
            lambda_att_sys_err_m=budget.lambda_att_sys_m,
        )

    def sys_interval_m(self, k: int) -> tuple[float, float]:
        """The systematic error (down, up) of λ_abs (k=0), λ_sca (1) or λ_att (2): the budget's
        one-sided sums, or the symmetric error when there is no budget."""
        if self.systematics is not None:
            return self.systematics.sys_down_m(k), self.systematics.sys_up_m(k)
        sym = (self.lambda_abs_sys_err_m, self.lambda_sca_sys_err_m, self.lambda_att_sys_err_m)[k]
        return sym, sym

    @property
    def has_result(self) -> bool:
        """True when at least one of the two lengths is measured or bounded."""
        return self.lambda_abs.status != UNCONSTRAINED or self.lambda_sca.status != UNCONSTRAINED


NUISANCES = (
    "distance_near",
    "distance_far",
    "emission_ratio",
    "psf_sigma",
    "focal_scale",
    "halo_scale",
)
UNITS = {
    "distance_near": "m",
    "distance_far": "m",
    "emission_ratio": "rel",
    "psf_sigma": "px",
    "focal_scale": "rel",
    "halo_scale": "rel",
}
