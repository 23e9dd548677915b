"""λ_abs and λ_sca of a frame set on disk: analyse, build or load templates, fit each wavelength.

The χ² method on top of `camcal.pipeline.analyze_folder` (which gives the
stacked profiles and the I_center λ_att the fit is checked against) and
`analysis.chisq` (the fit itself).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from analysis.attenuation import AttenuationResult, EmissionRatio, Geometry
from analysis.chisq import (
    ATT_CHECK_FLAG_SIGMA,
    ChiSquareFit,
    FitConfig,
    FitInputError,
    Nuisance,
    SettingProfiles,
    collect_settings,
    fit_wavelength,
)
from analysis.chisq.phase import combine_maps
from analysis.chisq.phase_results import PhaseConfig, PhaseMap
from analysis.chisq.systematics import SystematicsConfig, systematic_budget, variation_settings
from analysis.chisq.wavelength import phase_map
from analysis.transport.cache import TemplateCache
from analysis.transport.disk import disk_radius_px
from analysis.transport.scene import LEM_RADIUS_M
from analysis.transport.smooth import SmoothTemplates
from analysis.transport.smooth_build import build_smooth_templates
from analysis.transport.smooth_variants import higher_order_variants
from analysis.transport.source import HaloSource
from analysis.transport.template_settings import DEFAULT_LAMBDA_SCA_NODES_M
from analysis.transport.templates import TemplateSettings, build_template_grid
from camcal.core.frameset import FrameSetError
from camcal.core.parallel import process_pool
from camcal.pipeline import FrameSetAnalysis, Overrides, analyze_folder

#: Template kinds: smooth in all four optical parameters (exact first order + small-angle orders), or
#: the Monte Carlo grid (nodes in λ_sca, one phase function).
SMOOTH = "smooth"
MONTE_CARLO = "monte-carlo"
TEMPLATE_KINDS = (SMOOTH, MONTE_CARLO)

#: Focal length in pixels of the T-REX camera (2448 px across a 16° field of view in water).
TREX_FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
#: Largest allowed mismatch between the measured and expected disk radius before the fit refuses.
RADIUS_TOLERANCE = 0.03


@dataclass(frozen=True)
class FitOptions:
    """Choices of ``camcal fit`` beyond the frame set's own setup.

    The templates: camera ``focal_px`` (None: the setup's, the cameras' own where it names
    them), scattering-length nodes, Mie
    ⟨cos θ⟩, Rayleigh share, refractive index, Monte Carlo photons per node
    and seed, the cache directory (None: the default). ``min_frames``
    accepted frames per camera and wavelength are required; only
    ``wavelengths_nm`` are fitted if given. ``fit`` holds the χ² fit's own
    settings.
    """

    focal_px: float | None = None
    lambda_sca_nodes_m: tuple[float, ...] = DEFAULT_LAMBDA_SCA_NODES_M
    mie_g: float = 0.93
    rayleigh_fraction: float = 0.17
    refractive_index: float = 1.35
    n_photons: int = 1_000_000
    seed: int = 0
    cache_dir: str | None = None
    min_frames: int = 3
    workers: int | None = None
    wavelengths_nm: tuple[int, ...] | None = None
    fit: FitConfig = field(default_factory=FitConfig)
    systematics: SystematicsConfig | None = field(default_factory=SystematicsConfig)
    templates: str = SMOOTH
    float_phase: bool = True
    joint_phase: bool = True

    def __post_init__(self) -> None:
        if self.focal_px is not None and not self.focal_px > 0:
            raise ValueError(f"focal_px must be > 0, got {self.focal_px}")
        if not -1 < self.mie_g < 1:
            raise ValueError(f"mie_g (<cos theta>) must lie in (-1, 1), got {self.mie_g}")
        if not 0 <= self.rayleigh_fraction <= 1:
            raise ValueError(f"rayleigh_fraction must lie in [0, 1], got {self.rayleigh_fraction}")
        if not self.lambda_sca_nodes_m or min(self.lambda_sca_nodes_m) <= 0:
            raise ValueError(f"lambda_sca_nodes_m must be positive, got {self.lambda_sca_nodes_m}")
        if self.n_photons < 1000:
            raise ValueError(f"n_photons must be >= 1000, got {self.n_photons}")
        if self.min_frames < 1:
            raise ValueError(f"min_frames must be >= 1, got {self.min_frames}")
        if self.templates not in TEMPLATE_KINDS:
            raise ValueError(f"templates must be one of {', '.join(TEMPLATE_KINDS)}, got {self.templates!r}")
        if self.float_phase and self.templates != SMOOTH:
            raise ValueError(
                "the phase function is measured with the smooth templates only: pass --templates smooth, "
                "or --fix-phase to hold it at --mie-g / --rayleigh-fraction"
            )

    def fit_config(self) -> FitConfig:
        """The χ² fit's settings, with the phase function floated when asked."""
        if self.float_phase and self.fit.phase is None:
            return replace(self.fit, phase=PhaseConfig(), mie_g=self.mie_g)
        if not self.float_phase and self.fit.phase is not None:
            return replace(self.fit, phase=None)
        return self.fit

    def template_settings(self, geometry: Geometry, n_bands: int) -> TemplateSettings:
        return TemplateSettings.near_far(
            geometry.distance_near_m,
            geometry.distance_far_m,
            self.focal_px if self.focal_px is not None else TREX_FOCAL_PX,
            n_bands=n_bands,
            rayleigh_fraction=self.rayleigh_fraction,
            refractive_index=self.refractive_index,
            lambda_sca_nodes_m=self.lambda_sca_nodes_m,
            mie_g_nodes=(self.mie_g,),
            n_photons=self.n_photons,
            seed=self.seed,
        )


@dataclass(frozen=True)
class AttenuationCheck:
    """The fit checked against what it did not fit: the I_center λ_att and the calibrations.

    ``z`` is the fit's 1/λ_abs + 1/λ_sca against the I_center λ_att of the
    same frames, the difference over the errors added in quadrature (the
    fit's, with its systematic part, and the I_center error with its
    systematic part); ``agrees`` when |z| <= 2; ``flagged`` when |z| exceeds
    `ATT_CHECK_FLAG_SIGMA` (3): the two methods disagree beyond their
    errors, and ``advice`` says what to look at next.

    ``strained`` holds the nuisances the fit moved beyond
    `NUISANCE_FLAG_SIGMA` (3) of their calibrations (I0'/I0 pulled to half
    its lab value, a distance metres off): the frames do not follow the
    model with the calibration as given, whatever the λ_att check says
    (a wide systematic error on the fit's λ_att can hide it there).
    ``nuisance_advice`` says so and what to look at. Unless ``relief``
    (`SystematicBudget.phase_relief`): a phase function the data allow keeps
    every calibration within 3σ, so the phase function, which the budget's
    phase line covers, moved them; not flagged, and the advice says so.
    """

    lambda_att_fit_m: float
    lambda_att_fit_err_m: float
    lambda_att_icenter_m: float | None
    lambda_att_icenter_err_m: float | None
    z: float | None
    strained: tuple[Nuisance, ...] = ()
    relief: tuple[str, float, float] | None = None

    @property
    def agrees(self) -> bool | None:
        return None if self.z is None else bool(abs(self.z) <= 2.0)

    @property
    def flagged(self) -> bool:
        return self.z is not None and abs(self.z) > ATT_CHECK_FLAG_SIGMA

    @property
    def advice(self) -> str | None:
        """What to do about a flagged disagreement (None when not flagged)."""
        if not self.flagged or self.lambda_att_icenter_m is None:
            return None
        longer = self.lambda_att_fit_m > self.lambda_att_icenter_m
        return (
            f"λ_att from the fit ({self.lambda_att_fit_m:.1f} m) and from I_center "
            f"({self.lambda_att_icenter_m:.1f} m) differ by {abs(self.z or 0):.1f}σ: do not quote λ_abs and "
            "λ_sca from this fit yet. "
            + (
                "The fit gives the light too little attenuation: "
                if longer
                else "The fit gives the light too much attenuation: "
            )
            + "check the profile residuals near the disk's edge (PSF, a double image), the emission ratio "
            "I0'/I0 at this wavelength and the two distances (they move I_center's λ_att directly), then the "
            "systematic budget's ⟨cos θ⟩ and Rayleigh lines; refit with --mie-g / --rayleigh-fraction "
            "set to what the water is known to have."
        )

    @property
    def nuisances_flagged(self) -> bool:
        return bool(self.strained) and self.relief is None

    @property
    def nuisance_advice(self) -> str | None:
        """What to do about nuisances pulled beyond their calibrations (None when none is)."""
        if not self.strained:
            return None
        moved = "; ".join(_moved(n) for n in self.strained)
        if self.relief is not None:
            case, dchi2, pull = self.relief
            g, _, share = case.partition("/")
            return (
                f"at the nominal phase function the fit moved {moved}; refitted at ⟨cos θ⟩ {g}, Rayleigh "
                f"share {share} (the data allow it: Δχ² {dchi2:+.1f}) every calibration stays within "
                f"{pull:.1f}σ: the phase function moved them, and the budget's phase line covers it. Not "
                "flagged; a water whose ⟨cos θ⟩ is known makes the fit tighter (--mie-g)."
            )
        return (
            f"the fit moved {moved}: the frames do not follow the model with the calibration as "
            "given, so do not quote λ_abs and λ_sca from this fit. Check the values it moved where they "
            "were set (setup.json; a dive's calibration: `camcal calibration list`), whether the water "
            "changed while the frames were taken (λ_att per visit in `camcal export`: the fit takes one "
            "water), and the profile residuals for light the model cannot make (a double image, stray "
            "light)."
        )


#: How a nuisance reads in a sentence, and how its shift is written.
_NUISANCE_WORDS = {
    "distance_near": "the near camera's distance",
    "distance_far": "the far camera's distance",
    "emission_ratio": "I0'/I0",
    "psf_sigma": "the PSF's width",
    "focal_scale": "the focal length",
    "halo_scale": "the halo's scale",
}


def _moved(n: Nuisance) -> str:
    what = _NUISANCE_WORDS.get(n.name, n.name)
    if n.unit == "rel":
        by, prior = f"{100 * n.shift:+.1f} %", f"±{100 * n.sigma:.1f} %"
    else:
        by, prior = f"{n.shift:+.3g} {n.unit}", f"±{n.sigma:.3g} {n.unit}"
    return f"{what} by {by} ({n.pull:+.1f}σ of its {prior})"


@dataclass(frozen=True)
class FolderFit:
    """The χ² fits of a frame set, what they were checked against and what was skipped.

    ``skipped`` gives the reason per wavelength that was not fitted (or whose
    fit failed); ``notes`` what went wrong after a fit (a budget that failed).
    """

    analysis: FrameSetAnalysis = field(repr=False)
    fits: dict[int, ChiSquareFit] = field(repr=False)
    checks: dict[int, AttenuationCheck]
    skipped: dict[int, str]
    templates: TemplateSettings
    options: FitOptions
    geometry: Geometry
    notes: dict[int, str] = field(default_factory=dict)

    @property
    def has_result(self) -> bool:
        """True when some wavelength measured or bounded λ_abs or λ_sca."""
        return any(f.has_result for f in self.fits.values())


def _check(fit: ChiSquareFit, att: AttenuationResult | None) -> AttenuationCheck:
    fit_err = math.hypot(fit.lambda_att_err_m, fit.lambda_att_sys_err_m)
    strained = fit.strained_nuisances
    if att is None or att.lambda_att_m is None or att.total_err_m is None:
        return AttenuationCheck(fit.lambda_att_m, fit_err, None, None, None, strained, fit.phase_relief)
    err = math.hypot(fit_err, att.total_err_m)
    z = float((fit.lambda_att_m - att.lambda_att_m) / err) if err > 0 else None
    return AttenuationCheck(
        float(fit.lambda_att_m),
        float(fit_err),
        float(att.lambda_att_m),
        float(att.total_err_m),
        z,
        strained,
        fit.phase_relief,
    )


def _phase_maps(
    todo: dict[int, list[SettingProfiles]],
    grid: HaloSource,
    geometry: Geometry,
    ratios: dict[int, EmissionRatio],
    cfg: FitConfig,
    options: FitOptions,
    pool: ProcessPoolExecutor | None,
    stage: Callable[[str], Callable[[int, int], None] | None],
) -> dict[int, PhaseMap]:
    """Each wavelength's phase map (in the pool), combined across wavelengths when asked: Mie
    ⟨cos θ⟩ shared (`combine_maps`). Empty when the phase function is held fixed; a wavelength whose
    map failed is fitted with its own map (its fit then says why it fails)."""
    if cfg.phase is None:
        return {}
    jobs = [(wl, s, grid, geometry, ratios[wl], cfg) for wl, s in sorted(todo.items())]
    maps = {
        job[0]: res
        for job, res in zip(jobs, _map(_map_job, jobs, pool, stage("phase maps")), strict=True)
        if isinstance(res, PhaseMap)
    }
    return combine_maps(maps) if options.joint_phase and len(maps) > 1 else maps


def _map_job(
    args: tuple[int, list[SettingProfiles], HaloSource, Geometry, EmissionRatio, FitConfig],
) -> PhaseMap | str | None:
    try:
        return phase_map(*args)
    except (FitInputError, ValueError) as exc:
        return f"{args[0]} nm: no phase map: {exc}"


def _fit_job(
    args: tuple[int, list[SettingProfiles], HaloSource, Geometry, EmissionRatio, FitConfig, PhaseMap | None],
) -> ChiSquareFit | str:
    """One wavelength's fit, or why it failed (the other wavelengths go on)."""
    try:
        return fit_wavelength(*args)
    except (FitInputError, ValueError) as exc:
        return f"{args[0]} nm: the fit failed: {exc}"


def _budget_job(
    args: tuple[ChiSquareFit, list[SettingProfiles], HaloSource, Mapping[str, HaloSource], SystematicsConfig],
) -> ChiSquareFit | str:
    """The fit with its systematic budget attached, or why the budget failed."""
    fit = args[0]
    try:
        return fit.with_budget(systematic_budget(*args))
    except (FitInputError, ValueError) as exc:
        return f"{fit.wavelength_nm} nm: no systematic budget: {exc}"


def _map(
    fn: Callable[[Any], Any],
    jobs: list[Any],
    pool: ProcessPoolExecutor | None,
    report: Callable[[int, int], None] | None,
) -> list[Any]:
    """``fn`` over ``jobs``, in the pool when there is one and more than one job."""
    results = pool.map(fn, jobs) if pool is not None and len(jobs) > 1 else map(fn, jobs)
    out = []
    for res in results:
        out.append(res)
        if report:
            report(len(out), len(jobs))
    return out


def _setup_focal_px(an: FrameSetAnalysis, geometry: Geometry) -> float:
    """The focal length the setup gives both cameras (its own, or a camera's where it names one).

    Raises `FitInputError` when the two cameras' differ: the templates take one focal length.
    """
    cams = an.setup.cameras
    near, far = (
        (cams[c].focal_px if c in cams else None) or an.setup.focal_px
        for c in (geometry.near_camera, geometry.far_camera)
    )
    if abs(near - far) > 1e-6 * near:
        raise FitInputError(
            f"the setup gives the cameras different focal lengths ({geometry.near_camera}: {near:.0f} px, "
            f"{geometry.far_camera}: {far:.0f} px) and the templates take one: pass --focal-px"
        )
    return float(near)


def _check_disk_radii(an: FrameSetAnalysis, geometry: Geometry, focal_px: float) -> None:
    """Refuse a focal length that does not reproduce the measured LEM disks (the templates would not fit)."""
    for cam, dist in (
        (geometry.near_camera, geometry.distance_near_m),
        (geometry.far_camera, geometry.distance_far_m),
    ):
        radii = [
            f.radius_px
            for row, f in zip(an.rows, an.frames, strict=True)
            if row.camera == cam and f.ok and f.radius_px is not None
        ]
        if not radii:
            continue
        measured = float(np.median(radii))
        expected = disk_radius_px(dist, LEM_RADIUS_M, focal_px)
        if abs(measured / expected - 1.0) > RADIUS_TOLERANCE:
            raise FitInputError(
                f"camera {cam}: the LEM's disk measures {measured:.1f} px but a focal length of "
                f"{focal_px:.0f} px (--focal-px, else the setup's focal_px) and {dist} m give "
                f"{expected:.1f} px; pass the camera's focal length in pixels (about "
                f"{focal_px * measured / expected:.0f}) with --focal-px or in setup.json"
            )


def fit_folder(
    folder: Path,
    options: FitOptions | None = None,
    overrides: Overrides | None = None,
    *,
    progress: Callable[[str, int, int], None] | None = None,
) -> FolderFit:
    """Analyse a frame set and fit λ_abs, λ_sca for every wavelength that allows it.

    Raises `FrameSetError` for an unreadable set and `FitInputError` when no
    wavelength can be fitted (the message gives each wavelength's reason).
    """
    options = options or FitOptions()
    workers = options.workers or os.cpu_count() or 1
    report = _stage(progress, "analysing")
    an = analyze_folder(folder, overrides, workers=workers, progress=report)
    return fit_analysis(an, options, progress=progress)


def _stage(progress: Callable[[str, int, int], None] | None, name: str) -> Callable[[int, int], None] | None:
    return (lambda done, total: progress(name, done, total)) if progress else None


def fit_analysis(
    an: FrameSetAnalysis,
    options: FitOptions | None = None,
    *,
    progress: Callable[[str, int, int], None] | None = None,
) -> FolderFit:
    """Fit λ_abs, λ_sca for every wavelength of an analysed frame set (a folder's or a stored dive's).

    Raises `FitInputError` when no wavelength can be fitted (the message
    gives each wavelength's reason).
    """
    options = options or FitOptions()
    workers = options.workers or os.cpu_count() or 1

    def stage(name: str) -> Callable[[int, int], None] | None:
        return _stage(progress, name)

    cameras = sorted({r.camera for r in an.rows if not r.error})
    if len(cameras) < 2:
        have = ", ".join(cameras) or "none"
        raise FitInputError(
            f"the χ² fit needs frames from two cameras (near and far); the manifest has: {have}"
        )
    if an.geometry is None or an.result is None:
        raise FitInputError(an.problem or "no camera geometry")
    geometry = an.geometry
    if options.focal_px is None:
        options = replace(options, focal_px=_setup_focal_px(an, geometry))
    assert options.focal_px is not None
    _check_disk_radii(an, geometry, options.focal_px)
    ratios = {wl: EmissionRatio(r.value, r.err) for wl, r in an.setup.emission_ratio.items()}
    wavelengths = sorted({r.wavelength_nm for r in an.rows if not r.error and r.wavelength_nm})
    if options.wavelengths_nm is not None:
        missing = sorted(set(options.wavelengths_nm) - set(wavelengths))
        if missing:
            have = ", ".join(map(str, wavelengths)) or "none"
            raise FitInputError(f"no frames at {', '.join(map(str, missing))} nm (frames at: {have} nm)")
        wavelengths = [wl for wl in wavelengths if wl in options.wavelengths_nm]
    todo: dict[int, list[SettingProfiles]] = {}
    skipped: dict[int, str] = {}
    for wl in wavelengths:
        if wl not in ratios:
            skipped[wl] = f"{wl} nm: no emission ratio I0'/I0 in setup.json or --ratio"
            continue
        try:
            todo[wl] = collect_settings(
                an.result.stacks, wl, geometry.near_camera, geometry.far_camera, options.min_frames
            )
        except FitInputError as exc:
            skipped[wl] = str(exc)
    if not todo:
        reasons = "; ".join(skipped.values()) or "no frames"
        raise FitInputError(f"nothing to fit: {reasons}")
    n_bands = min(len(p.mean_gray) for s in todo.values() for sp in s for p in (sp.near, sp.far))
    n_bands -= n_bands % 8
    tsettings = options.template_settings(geometry, n_bands)
    notes: dict[int, str] = {}
    pool = process_pool(workers) if workers > 1 else None  # one pool: templates, fits and budgets
    try:
        grid = _templates(tsettings, options, pool, stage("templates"))
        cfg = options.fit_config()
        maps = _phase_maps(todo, grid, geometry, ratios, cfg, options, pool, stage)
        jobs = [(wl, s, grid, geometry, ratios[wl], cfg, maps.get(wl)) for wl, s in sorted(todo.items())]
        fits: dict[int, ChiSquareFit] = {}
        for job, res in zip(jobs, _map(_fit_job, jobs, pool, stage("fitting")), strict=True):
            if isinstance(res, str):
                skipped[job[0]] = res
            else:
                fits[job[0]] = res
        if not fits:
            raise FitInputError(f"nothing could be fitted: {'; '.join(skipped.values())}")
        if options.systematics is not None:
            fits = _with_budgets(fits, todo, grid, options, workers, pool, stage, notes)
    finally:
        if pool is not None:
            pool.shutdown()
    checks = {wl: _check(f, an.result.attenuation.get(wl)) for wl, f in fits.items()}
    return FolderFit(an, fits, checks, skipped, tsettings, options, geometry, notes)


def _templates(
    settings: TemplateSettings,
    options: FitOptions,
    pool: ProcessPoolExecutor | None,
    progress: Callable[[int, int], None] | None,
) -> HaloSource:
    """The fit's templates: smooth ones, or the Monte Carlo grid (`FitOptions.templates`)."""
    cache = TemplateCache(options.cache_dir)
    if options.templates == SMOOTH:
        return build_smooth_templates(settings, cache, executor=pool, progress=progress)
    return build_template_grid(settings, cache, executor=pool, progress=progress)


def _with_budgets(
    fits: dict[int, ChiSquareFit],
    todo: dict[int, list[SettingProfiles]],
    grid: HaloSource,
    options: FitOptions,
    workers: int,
    pool: ProcessPoolExecutor | None,
    stage: Callable[[str], Callable[[int, int], None] | None],
    notes: dict[int, str],
) -> dict[int, ChiSquareFit]:
    """Attach each fit's systematic budget; the alternative templates are built (or loaded) first."""
    assert options.systematics is not None
    lam_sca = [f.lambda_sca_m for f in fits.values()]
    cache = TemplateCache(options.cache_dir)
    if options.templates == SMOOTH:
        smooth = _smooth_variations(grid, options, pool, stage)
        return _attach_budgets(fits, todo, grid, smooth, options.systematics, pool, stage, notes)
    variants = variation_settings(grid.settings, lam_sca, options.systematics)
    n_pieces = sum(len(v.mie_g_nodes) * (1 + len(v.lambda_sca_nodes_m)) for v in variants.values())
    report = stage("sys templates")
    done = 0
    vgrids: dict[str, HaloSource] = {}
    for name, vs in variants.items():
        base = done

        def piece(d: int, _total: int, base: int = base) -> None:
            if report:
                report(base + d, n_pieces)

        vgrids[name] = build_template_grid(vs, cache, executor=pool, progress=piece)
        done += len(vs.mie_g_nodes) * (1 + len(vs.lambda_sca_nodes_m))
    return _attach_budgets(fits, todo, grid, vgrids, options.systematics, pool, stage, notes)


def _smooth_variations(
    grid: HaloSource,
    options: FitOptions,
    pool: ProcessPoolExecutor | None,
    stage: Callable[[str], Callable[[int, int], None] | None],
) -> dict[str, HaloSource]:
    """The budget's templates with smooth ones: the other emission shapes, the small-angle orders
    scaled by their stated accuracy (cheap: tables of the same geometry, built once and cached),
    and with the phase function held fixed the same templates at each Rayleigh share of the prior
    (the share a template defaults to is its settings')."""
    assert options.systematics is not None
    cache = TemplateCache(options.cache_dir)
    out: dict[str, HaloSource] = {}
    for shape in options.systematics.emission_shapes:
        settings = replace(grid.settings, emission_shape=shape)
        report = stage("sys templates")
        out[f"emission={shape}"] = build_smooth_templates(settings, cache, executor=pool, progress=report)
    assert isinstance(grid, SmoothTemplates)
    out.update(higher_order_variants(grid))
    if not options.float_phase:  # held fixed: the budget's phase line refits over the priors
        for share in options.systematics.rayleigh_values(grid.settings.rayleigh_fraction):
            held = replace(grid.settings, rayleigh_fraction=share)
            out[f"phase:rayleigh={share:g}"] = replace(grid, settings=held)
    return out


def _attach_budgets(
    fits: dict[int, ChiSquareFit],
    todo: dict[int, list[SettingProfiles]],
    grid: HaloSource,
    vgrids: Mapping[str, HaloSource],
    config: SystematicsConfig,
    pool: ProcessPoolExecutor | None,
    stage: Callable[[str], Callable[[int, int], None] | None],
    notes: dict[int, str],
) -> dict[int, ChiSquareFit]:
    """Each fit with its budget on the variations' templates (in the pool)."""
    jobs = [(f, todo[wl], grid, vgrids, config) for wl, f in sorted(fits.items())]
    out = dict(fits)
    for job, res in zip(jobs, _map(_budget_job, jobs, pool, stage("systematics")), strict=True):
        wl = job[0].wavelength_nm
        if isinstance(res, str):
            notes[wl] = res
        else:
            out[wl] = res
    return out


__all__ = [
    "TREX_FOCAL_PX",
    "AttenuationCheck",
    "FitInputError",
    "FitOptions",
    "FolderFit",
    "FrameSetError",
    "fit_analysis",
    "fit_folder",
]
