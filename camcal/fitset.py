"""λ_abs and λ_sca of a frame set on disk: analyse, build or load templates, fit each wavelength.

The χ² method on top of `camcal.pipeline.analyze_folder` (which gives the
stacked profiles and the I_center λ_att the fit is checked against) and
`analysis.chisq` (the fit itself).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.attenuation import AttenuationResult, EmissionRatio, Geometry
from analysis.chisq import (
    ChiSquareFit,
    FitConfig,
    FitInputError,
    SettingProfiles,
    collect_settings,
    fit_wavelength,
)
from analysis.transport.cache import TemplateCache
from analysis.transport.disk import disk_radius_px
from analysis.transport.scene import LEM_RADIUS_M
from analysis.transport.templates import (
    DEFAULT_LAMBDA_SCA_NODES_M,
    TemplateGrid,
    TemplateSettings,
    build_template_grid,
)
from camcal.core import __version__
from camcal.core.frameset import FrameSetError
from camcal.pipeline import FrameSetAnalysis, Overrides, analyze_folder

#: Focal length in pixels of the T-REX camera (2448 px across a 16° field of view in water).
TREX_FOCAL_PX = 1224.0 / math.tan(math.radians(8.0))
#: Largest allowed mismatch between the measured and expected disk radius before the fit refuses.
RADIUS_TOLERANCE = 0.03


@dataclass(frozen=True)
class FitOptions:
    """Choices of ``camcal fit`` beyond the frame set's own setup.

    The templates: camera ``focal_px``, scattering-length nodes, Mie
    ⟨cos θ⟩, Rayleigh share, refractive index, Monte Carlo photons per node
    and seed, the cache directory (None: the default). ``min_frames``
    accepted frames per camera and wavelength are required; only
    ``wavelengths_nm`` are fitted if given. ``fit`` holds the χ² fit's own
    settings.
    """

    focal_px: float = TREX_FOCAL_PX
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

    def __post_init__(self) -> None:
        if not self.focal_px > 0:
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

    def template_settings(self, geometry: Geometry, n_bands: int) -> TemplateSettings:
        return TemplateSettings.near_far(
            geometry.distance_near_m,
            geometry.distance_far_m,
            self.focal_px,
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
    """The fit's 1/λ_abs + 1/λ_sca against the I_center λ_att of the same frames.

    ``z`` is the difference over the two errors added in quadrature (the
    I_center error with its systematic part); ``agrees`` when |z| <= 2.
    """

    lambda_att_fit_m: float
    lambda_att_fit_err_m: float
    lambda_att_icenter_m: float | None
    lambda_att_icenter_err_m: float | None
    z: float | None

    @property
    def agrees(self) -> bool | None:
        return None if self.z is None else bool(abs(self.z) <= 2.0)


@dataclass(frozen=True)
class FolderFit:
    """The χ² fits of a frame set, what they were checked against and what was skipped."""

    analysis: FrameSetAnalysis = field(repr=False)
    fits: dict[int, ChiSquareFit] = field(repr=False)
    checks: dict[int, AttenuationCheck]
    skipped: dict[int, str]
    templates: TemplateSettings
    options: FitOptions
    geometry: Geometry


def _check(fit: ChiSquareFit, att: AttenuationResult | None) -> AttenuationCheck:
    if att is None or att.lambda_att_m is None or att.total_err_m is None:
        return AttenuationCheck(fit.lambda_att_m, fit.lambda_att_err_m, None, None, None)
    err = math.hypot(fit.lambda_att_err_m, att.total_err_m)
    z = float((fit.lambda_att_m - att.lambda_att_m) / err) if err > 0 else None
    return AttenuationCheck(
        float(fit.lambda_att_m),
        float(fit.lambda_att_err_m),
        float(att.lambda_att_m),
        float(att.total_err_m),
        z,
    )


def _fit_job(
    args: tuple[int, list[SettingProfiles], TemplateGrid, Geometry, EmissionRatio, FitConfig],
) -> ChiSquareFit:
    return fit_wavelength(*args)


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
                f"camera {cam}: the LEM's disk measures {measured:.1f} px but --focal-px {focal_px:.0f} "
                f"and {dist} m give {expected:.1f} px; pass the camera's focal length in pixels "
                f"(about {focal_px * measured / expected:.0f})"
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
    grid = build_template_grid(
        tsettings, TemplateCache(options.cache_dir), workers=workers, progress=stage("templates")
    )
    jobs = [(wl, s, grid, geometry, ratios[wl], options.fit) for wl, s in sorted(todo.items())]
    fits: dict[int, ChiSquareFit] = {}
    report = stage("fitting")
    if workers > 1 and len(jobs) > 1:
        with ProcessPoolExecutor(max_workers=min(workers, len(jobs))) as pool:
            for job, res in zip(jobs, pool.map(_fit_job, jobs), strict=True):
                fits[job[0]] = res
                if report:
                    report(len(fits), len(jobs))
    else:
        for job in jobs:
            fits[job[0]] = _fit_job(job)
            if report:
                report(len(fits), len(jobs))
    checks = {wl: _check(f, an.result.attenuation.get(wl)) for wl, f in fits.items()}
    return FolderFit(an, fits, checks, skipped, tsettings, options, geometry)


def _r(x: float | None, digits: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def _sig(values: Any, digits: int = 5) -> Any:
    """Nested lists of floats at ``digits`` significant digits; NaN and inf become None."""
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim == 0:
        x = float(arr)
        return float(f"{x:.{digits}g}") if math.isfinite(x) else None
    return [_sig(v, digits) for v in arr]


def fit_detail(fit: ChiSquareFit) -> dict[str, Any]:
    """The Δχ² map and each setting's normalised profiles (data, error, model, halo, bands used)."""
    c = fit.contour
    return {
        "contour": {
            "lambda_abs_m": _sig(c.lambda_abs_m),
            "lambda_sca_m": _sig(c.lambda_sca_m),
            "delta_chi2": _sig(c.delta_chi2, 4),
        },
        "profiles": [
            {
                "exposure_s": m.exposure_s,
                "gain_db": m.gain_db,
                "radius_px": _sig(m.radius_px),
                "data": _sig(m.data),
                "error": _sig(m.error, 3),
                "model": _sig(m.model),
                "halo": _sig(m.halo),
                "used": np.asarray(m.used, dtype=bool).tolist(),
            }
            for m in fit.settings
        ],
    }


def fit_entry(f: ChiSquareFit, chk: AttenuationCheck) -> dict[str, Any]:
    """One wavelength's fit as ``camcal fit --json`` writes it (the report and the figures read it)."""
    return {
        "wavelength_nm": f.wavelength_nm,
        "lambda_abs_m": _r(f.lambda_abs_m, 3),
        "lambda_abs_err_m": _r(f.lambda_abs_err_m, 3),
        "lambda_abs_interval_m": [_r(v, 3) for v in f.lambda_abs_interval_m],
        "lambda_sca_m": _r(f.lambda_sca_m, 3),
        "lambda_sca_err_m": _r(f.lambda_sca_err_m, 3),
        "lambda_sca_interval_m": [_r(v, 3) for v in f.lambda_sca_interval_m],
        "lambda_sca_sys_err_m": _r(f.lambda_sca_sys_err_m, 3),
        "correlation": _r(f.correlation),
        "lambda_att_fit_m": _r(chk.lambda_att_fit_m, 3),
        "lambda_att_fit_err_m": _r(chk.lambda_att_fit_err_m, 3),
        "lambda_att_icenter_m": _r(chk.lambda_att_icenter_m, 3),
        "lambda_att_icenter_err_m": _r(chk.lambda_att_icenter_err_m, 3),
        "att_check_z": _r(chk.z, 3),
        "att_check_agrees": chk.agrees,
        "chi2": _r(f.chi2, 2),
        "ndof": f.ndof,
        "mie_g": f.mie_g,
        "at_edge": list(f.at_edge),
        "nuisances": [
            {
                "name": n.name,
                "unit": n.unit,
                "shift": _r(n.shift, 5),
                "sigma": _r(n.sigma, 5),
                "pull": _r(n.pull, 3),
            }
            for n in f.nuisances
        ],
        "settings": [{"exposure_s": s.exposure_s, "gain_db": s.gain_db} for s in f.settings],
        "n_evaluations": f.n_evaluations,
        **fit_detail(f),
    }


def to_json(result: FolderFit) -> dict[str, Any]:
    """The ``camcal fit --json`` document."""
    out = [fit_entry(f, result.checks[wl]) for wl, f in sorted(result.fits.items())]
    return {
        "fits": out,
        "skipped": {str(k): v for k, v in sorted(result.skipped.items())},
        "inputs": {
            "folder": str(result.analysis.folder),
            "setup": result.analysis.setup.to_json(),
            "geometry": asdict(result.geometry),
            "templates": asdict(result.templates),
            "fit": asdict(result.options.fit),
        },
        "software": {"name": "camcal", "version": __version__},
    }


__all__ = [
    "TREX_FOCAL_PX",
    "AttenuationCheck",
    "FitInputError",
    "FitOptions",
    "FolderFit",
    "FrameSetError",
    "fit_analysis",
    "fit_entry",
    "fit_folder",
    "to_json",
]
