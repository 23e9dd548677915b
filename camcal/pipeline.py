"""Analyse a frame set on disk: decode on all cores, I_center per frame, λ_att per wavelength."""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from analysis import (
    EmissionRatio,
    FrameAnalysis,
    FrameConfig,
    FrameRecord,
    Geometry,
    Reason,
    SetResult,
    Setting,
    analyze_frame,
    analyze_records,
    rejected,
)
from camcal.core import __version__
from camcal.core.frameset import FrameSetError, ManifestRow, Setup, read_manifest, read_setup
from camcal.core.images import FrameReadError, read_frame_scaled
from camcal.core.parallel import map_in_threads


@dataclass(frozen=True)
class Overrides:
    """Command-line values that replace those of setup.json."""

    distances_m: Mapping[str, float] | None = None
    distance_errs_m: Mapping[str, float] | None = None
    emission_ratios: Mapping[int, tuple[float, float]] | None = None
    linear_range: tuple[float, float] | None = None
    clock_offsets_s: Mapping[str, float] | None = None

    def apply(self, setup: Setup) -> Setup:
        data = setup.model_dump()
        for cam, off in (self.clock_offsets_s or {}).items():
            if cam not in data["cameras"]:
                raise FrameSetError(f"clock offset given for camera {cam}, which the setup does not have")
            data["cameras"][cam]["clock_offset_s"] = off
        for cam, d in (self.distances_m or {}).items():
            data["cameras"].setdefault(cam, {"distance_m": d, "distance_err_m": 0.0})
            data["cameras"][cam]["distance_m"] = d
        for cam, e in (self.distance_errs_m or {}).items():
            if cam not in data["cameras"]:
                raise FrameSetError(f"distance error given for camera {cam} without a distance")
            data["cameras"][cam]["distance_err_m"] = e
        for wl, (v, e) in (self.emission_ratios or {}).items():
            data["emission_ratio"][wl] = {"value": v, "err": e}
        if self.linear_range is not None:
            data["linear_range"] = self.linear_range
        from camcal.core.frameset import parse_setup

        return parse_setup(data, "options")


def geometry_from_setup(setup: Setup, cameras_present: set[str]) -> Geometry:
    """Near and far camera: of those in the manifest with a distance, the nearest and farthest."""
    known = sorted(
        (c for c in cameras_present if c in setup.cameras),
        key=lambda c: setup.cameras[c].distance_m,
    )
    if not cameras_present:
        raise FrameSetError("the manifest lists no usable frame (no rows, or none with valid values)")
    if len(known) < 2:
        have = ", ".join(sorted(cameras_present))
        raise FrameSetError(
            f"λ_att needs two cameras with distances in setup.json; manifest cameras: {have}, "
            f"setup cameras: {', '.join(sorted(setup.cameras))}"
        )
    near, far = setup.cameras[known[0]], setup.cameras[known[-1]]
    try:
        return Geometry(
            known[0], known[-1], near.distance_m, near.distance_err_m, far.distance_m, far.distance_err_m
        )
    except ValueError as exc:
        raise FrameSetError(f"setup.json: {exc}") from exc


def analyze_file(folder: str, row: ManifestRow, config: FrameConfig) -> FrameAnalysis:
    """Read and analyse one manifest row; problems become a rejected result."""
    if row.error:
        return rejected(Reason.BAD_METADATA, row.error)
    try:
        frame, top = read_frame_scaled(Path(folder) / row.file)
    except FrameReadError as exc:
        return rejected(exc.reason, exc.detail)
    result = analyze_frame(frame, config, full_scale=top)
    if not result.ok:
        # Rejected frames travel back without their crop: nothing downstream needs it.
        result = replace(result, crop=None, profile=None)
    return result


def _analyze_batch(args: tuple[str, list[ManifestRow], Mapping[str, FrameConfig]]) -> list[FrameAnalysis]:
    """Analyse rows with their camera's config (the one under "" for a camera the setup lacks)."""
    folder, rows, configs = args
    return [analyze_file(folder, row, configs.get(row.camera) or configs[""]) for row in rows]


@dataclass(frozen=True)
class FrameSetAnalysis:
    """A frame set's rows, their analyses, and the combined result."""

    folder: Path
    setup: Setup
    rows: list[ManifestRow]
    frames: list[FrameAnalysis]
    result: SetResult | None
    geometry: Geometry | None
    problem: str | None
    #: What was kept but looks wrong (`Setup.warnings`, cameras λ_att cannot use), for the person.
    warnings: list[str] = field(default_factory=list)

    def counts(self) -> Counter[str]:
        return Counter("ok" if f.ok else (f.reason or "rejected") for f in self.frames)


def analyze_folder(
    folder: Path,
    overrides: Overrides | None = None,
    *,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FrameSetAnalysis:
    """Analyse every frame of a frame set in parallel and combine the results.

    Raises `FrameSetError` for a missing manifest, a missing column or an
    invalid setup. Everything wrong with a single frame is a rejected frame.
    """
    rows, setup = load_frame_set(folder, overrides)
    return analyze_rows(folder, rows, setup, workers=workers, progress=progress)


def load_frame_set(folder: Path, overrides: Overrides | None = None) -> tuple[list[ManifestRow], Setup]:
    """Manifest rows and the effective setup; raises `FrameSetError` if either is unusable."""
    rows = read_manifest(Path(folder))
    setup = read_setup(Path(folder))
    if overrides:
        setup = overrides.apply(setup)
    return rows, setup


def analyze_rows(
    folder: Path,
    rows: list[ManifestRow],
    setup: Setup,
    *,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> FrameSetAnalysis:
    """Analyse the given rows of a frame set (see `analyze_folder`)."""
    folder = Path(folder)
    configs = {cam: FrameConfig(**setup.frame_settings(cam)) for cam in {r.camera for r in rows}}
    configs[""] = FrameConfig(**setup.frame_settings(None))
    workers = workers or os.cpu_count() or 1
    frames: list[FrameAnalysis] = []
    batch = 4
    batches = [(str(folder), rows[i : i + batch], configs) for i in range(0, len(rows), batch)]
    if workers <= 1 or len(rows) <= batch:
        results = map(_analyze_batch, batches)
        for out in results:
            frames.extend(out)
            if progress:
                progress(len(frames), len(rows))
    else:
        finished = 0

        def count(out: list[FrameAnalysis]) -> None:
            nonlocal finished
            finished += len(out)
            if progress:
                progress(finished, len(rows))

        for out in map_in_threads(_analyze_batch, batches, workers, count):
            frames.extend(out)

    records = [
        FrameRecord(row.camera, Setting(row.wavelength_nm, row.exposure_s, row.gain_db), f)
        for row, f in zip(rows, frames, strict=True)
        if not row.error
    ]
    geometry: Geometry | None = None
    result: SetResult | None = None
    problem: str | None = None
    try:
        geometry = geometry_from_setup(setup, {r.camera for r in rows if not r.error})
    except FrameSetError as exc:
        problem = str(exc)
    if geometry is not None:
        ratios = {wl: EmissionRatio(r.value, r.err) for wl, r in setup.emission_ratio.items()}
        result = analyze_records(records, geometry, ratios, tuple(setup.linear_range))  # type: ignore[arg-type]
    warnings = setup.warnings() + _unused_cameras(rows, setup, geometry)
    return FrameSetAnalysis(folder, setup, rows, frames, result, geometry, problem, warnings)


def _unused_cameras(rows: list[ManifestRow], setup: Setup, geometry: Geometry | None) -> list[str]:
    """The manifest's cameras whose frames λ_att does not use: not in the setup, or between the two."""
    n = Counter(r.camera for r in rows if not r.error)
    out = []
    for cam in sorted(n):
        if cam not in setup.cameras:
            out.append(
                f"camera {cam!r} ({n[cam]} frames) is not in setup.json (its cameras: "
                f"{', '.join(sorted(setup.cameras))}): its frames are measured but not used for λ_att; "
                "name it in setup.json or correct the manifest"
            )
        elif geometry is not None and cam not in (geometry.near_camera, geometry.far_camera):
            out.append(
                f"camera {cam!r} ({n[cam]} frames) lies between the nearest and the farthest: not used"
            )
    return out


def _num(x: float | None, digits: int = 4) -> float | None:
    if x is None or not math.isfinite(x):
        return None
    return round(float(x), digits)


def to_json(an: FrameSetAnalysis) -> dict[str, Any]:
    """The ``camcal analyze --json`` document (the frame-set spec, plus details)."""
    attenuation = []
    pairs = []
    if an.result is not None:
        for wl, res in sorted(an.result.attenuation.items()):
            attenuation.append(
                {
                    "wavelength_nm": wl,
                    "lambda_att_m": _num(res.lambda_att_m, 3),
                    "stat_err_m": _num(res.stat_err_m, 3),
                    "sys_err_m": _num(res.sys_err_m, 3),
                    "n_pairs": res.n_pairs,
                    "chi2_ndof": _num(res.chi2_ndof, 3),
                    "emission_ratio": res.emission_ratio.value,
                    "note": res.note,
                }
            )
        for wl, plist in an.result.pairs.items():
            for p in plist:
                pairs.append(
                    {
                        "wavelength_nm": wl,
                        "exposure_s": p.exposure_s,
                        "gain_db": p.gain_db,
                        "i_near": _num(p.i_near_gray),
                        "i_near_err": _num(p.i_near_err_gray),
                        "i_far": _num(p.i_far_gray),
                        "i_far_err": _num(p.i_far_err_gray),
                        "n_near": p.n_near,
                        "n_far": p.n_far,
                        "lambda_att_m": _num(p.lambda_att_m, 3),
                        "stat_err_m": _num(p.stat_err_m, 3),
                        "sys_err_m": _num(p.sys_err_m, 3),
                    }
                )
    frames = []
    for row, f in zip(an.rows, an.frames, strict=True):
        frames.append(
            {
                "file": row.file,
                "camera": row.camera,
                "wavelength_nm": row.wavelength_nm or None,
                "exposure_s": _num(row.exposure_s, 6),
                "gain_db": _num(row.gain_db, 3),
                "status": f.status,
                "reason": f.reason,
                "detail": f.detail,
                "centroid_px": [_num(f.centroid_px[0], 3), _num(f.centroid_px[1], 3)]
                if f.centroid_px
                else None,
                "radius_px": _num(f.radius_px, 2),
                "i_center": _num(f.i_center_gray),
                "i_center_err": _num(f.i_center_err_gray),
                "center_gray": _num(f.center_gray),
                "background": _num(f.background_gray),
            }
        )
    linearity = []
    if an.result is not None:
        for chk in an.result.linearity:
            for kind, fit, fixed in (
                ("exposure", chk.exposure, chk.fixed_gain_db),
                ("gain", chk.gain, chk.fixed_exposure_s),
            ):
                if fit is None:
                    continue
                linearity.append(
                    {
                        "camera": chk.camera,
                        "wavelength_nm": chk.wavelength_nm,
                        "sweep": kind,
                        "fixed": fixed,
                        "slope": _num(fit.slope, 4),
                        "intercept": _num(fit.intercept_gray),
                        "r2": _num(fit.r2, 5),
                        "n_used": fit.n_used,
                        "linear_max_gray": _num(fit.linear_max_gray, 2),
                        "knee_x": fit.knee_x,
                    }
                )
    return {
        "attenuation": attenuation,
        "frames": frames,
        "pairs": pairs,
        "linearity": linearity,
        "skipped": {str(k): v for k, v in (an.result.skipped if an.result else {}).items()},
        "problem": an.problem,
        "warnings": an.warnings,
        "summary": dict(an.counts()),
        "inputs": {"folder": str(an.folder), "setup": an.setup.to_json()},
        "software": {"name": "camcal", "version": __version__},
    }
