"""``camcal calibrate air-scan`` and ``tank-scan``: frame sets whose source distance changes per frame.

* air-scan (the long-distance test in air, 5-41 m): the centre gray stays
  constant, the total gray falls as 1/L², the disk radius as 1/L (Hough);
* tank-scan (a small source along a water tank, 1-3 m): the centre gray
  decays as exp(-L/λ_att) in water, and not in air.

Every frame needs its LEM-to-camera distance (``distance_m``); a distance
reading error (``distance_err_m``, or ``--distance-err``) enters the fits.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from analysis.calibration import (
    DecayFit,
    MediumComparison,
    PinholeFit,
    PowerLawFit,
    compare_media,
    decay_fit,
    measure_source,
    pinhole_fit,
    power_law_fit,
    reduce_scan,
)
from analysis.frame import FrameConfig
from camcal.calibrate.common import (
    CalibrationError,
    FrameOutcome,
    LabCalibration,
    Selection,
    line_fit_json,
    map_frames,
    no_usable_frames,
    normalisation,
    num,
    rejected_outcome,
    require_column,
    result_document,
    select_rows,
    value,
)
from camcal.calibrate.emission import measure_i_center
from camcal.core.frameset import ManifestRow

#: Errors of a Hough radius. On simulated disks of 12-93 px radius behind a
#: 1.2 px PSF, single fits scatter by 0.01-0.03 px (statistical, per frame)
#: and are off by up to ±0.06 px, inward for small disks (a blurred edge's
#: steepest point sits ~sigma²/2r inside it), outward for large ones. That
#: offset does not average out over repeats or distances: it enters the
#: focal length as a systematic error (`pinhole_fit`).
HOUGH_RADIUS_ERR_PX = 0.03
HOUGH_RADIUS_SYS_PX = 0.06
#: The LEM: 0.43 m across. The tank's Teflon ball: 2.5 cm.
LEM_DIAMETER_M = 0.43
TANK_SOURCE_DIAMETER_M = 0.025


def _with_distance_errors(rows: list[ManifestRow], distance_err_m: float | None) -> list[ManifestRow]:
    """Rows whose distance error is ``distance_err_m`` where given, else the manifest's (or 0)."""
    if distance_err_m is not None and distance_err_m < 0:
        raise CalibrationError(f"--distance-err must be >= 0, got {distance_err_m}")
    out = []
    for r in rows:
        err = distance_err_m if distance_err_m is not None else (r.distance_err_m or 0.0)
        out.append(replace(r, distance_err_m=err))
    return out


def _scan_rows(folder: Path, command: str, camera: str | None, distance_err_m: float | None) -> Selection:
    sel = select_rows(folder, command, camera)
    require_column(sel.rows, "distance_m", command, "the source-to-camera distance of each frame")
    return replace(sel, rows=_with_distance_errors(sel.rows, distance_err_m))


def _measure_air(config: FrameConfig, row: ManifestRow, frame: np.ndarray) -> FrameOutcome:
    m = measure_source(frame, config)
    a = m.analysis
    if not a.ok:
        return rejected_outcome(row, a.reason or "rejected", a.detail, center_gray=a.center_gray)
    assert m.total is not None
    norm = normalisation(row)
    values: dict[str, Any] = {
        "i_center_gray_per_s": a.i_center_gray / norm,  # type: ignore[operator]
        "i_center_err_gray_per_s": a.i_center_err_gray / norm,  # type: ignore[operator]
        "total_gray_per_s": m.total.total_gray / norm,
        "total_err_gray_per_s": m.total.total_err_gray / norm,
        "total_complete": m.total.complete,
        "x_px": a.centroid_px[0] if a.centroid_px else None,
        "y_px": a.centroid_px[1] if a.centroid_px else None,
        "radius_px": a.radius_px,
        "hough_radius_px": m.hough_radius_px,
        "background_gray": a.background_gray,
    }
    return FrameOutcome(row, "ok", values=values)


def _points(frames: list[FrameOutcome], key: str, err_key: str | None, err_const: float = 0.0) -> list[Any]:
    use = [f for f in frames if f.values.get(key) is not None]
    return reduce_scan(
        [f.row.distance_m for f in use],  # type: ignore[misc]
        [f.row.distance_err_m for f in use],  # type: ignore[misc]
        [f.values[key] for f in use],
        [f.values[err_key] if err_key else err_const for f in use],
    )


@dataclass(frozen=True)
class AirScanResult:
    """One wavelength of an air scan: the three laws' fits (None where the data do not allow one)."""

    wavelength_nm: int
    centre: DecayFit
    total: PowerLawFit | None
    pinhole: PinholeFit | None
    notes: tuple[str, ...]


AirScanCalibration = LabCalibration[int, AirScanResult]


def run_air_scan(
    folder: Path,
    *,
    camera: str | None = None,
    source_diameter_m: float = LEM_DIAMETER_M,
    distance_err_m: float | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> AirScanCalibration:
    """Fit centre gray, total gray and Hough radius against distance, per wavelength.

    Frames marked ``medium=water`` do not belong in an air scan and stop
    the command. Frames whose source is cut by the frame edge are left out
    of the total (their ``total_complete`` is false).
    """
    if not source_diameter_m > 0:
        raise CalibrationError(f"--source-diameter must be > 0, got {source_diameter_m}")
    sel = _scan_rows(folder, "air-scan", camera, distance_err_m)
    wet = [r for r in sel.rows if r.medium == "water"]
    if wet:
        raise CalibrationError(
            f"air-scan: {len(wet)} frames are marked medium=water (first {wet[0].file}); use tank-scan"
        )
    config = FrameConfig(linear_range_gray=tuple(sel.setup.linear_range))  # type: ignore[arg-type]
    frames = map_frames(
        sel.folder, sel.rows, partial(_measure_air, config), workers=workers, progress=progress
    )
    if not any(f.ok for f in frames):
        raise no_usable_frames("air-scan", frames)
    results = {}
    for wl in sorted({f.row.wavelength_nm for f in frames if f.ok}):
        good = [f for f in frames if f.ok and f.row.wavelength_nm == wl]
        notes = []
        try:
            centre = decay_fit(_points(good, "i_center_gray_per_s", "i_center_err_gray_per_s"))
        except ValueError as exc:
            raise CalibrationError(f"air-scan at {wl} nm: centre gray: {exc}") from None
        complete = [f for f in good if f.values["total_complete"]]
        total = pinhole = None
        try:
            total = power_law_fit(_points(complete, "total_gray_per_s", "total_err_gray_per_s"))
        except ValueError as exc:
            notes.append(f"no 1/L² fit: {exc}")
        try:
            radii = _points(good, "hough_radius_px", None, HOUGH_RADIUS_ERR_PX)
            pinhole = pinhole_fit(radii, source_diameter_m / 2.0, HOUGH_RADIUS_SYS_PX)
        except ValueError as exc:
            notes.append(f"no pinhole fit: {exc}")
        results[wl] = AirScanResult(wl, centre, total, pinhole, tuple(notes))
    inputs = {"source_diameter_m": source_diameter_m, "distance_err_m": distance_err_m}
    return AirScanCalibration(sel, frames, results, inputs)


def _decay_json(fit: DecayFit) -> dict[str, Any]:
    return {
        "mu_per_m": num(fit.mu_per_m),
        "mu_err_per_m": num(fit.mu_err_per_m),
        "amplitude_gray_per_s": num(fit.amplitude),
        "amplitude_err_gray_per_s": num(fit.amplitude_err),
        "n_frames": [p.n_frames for p in fit.points],
        "line": line_fit_json(fit.fit),
    }


def air_scan_values(cal: AirScanCalibration) -> list[dict[str, Any]]:
    out = []
    for wl, r in sorted(cal.results.items()):
        c = r.centre
        out.append(value("centre_mu_per_m", c.mu_per_m, c.mu_err_per_m, "1/m", wavelength_nm=wl))
        out.append(
            value("centre_gray_per_s", c.amplitude, c.amplitude_err, "gray/s at 0 dB", wavelength_nm=wl)
        )
        span = max(p.distance_m for p in c.points) - min(p.distance_m for p in c.points)
        out.append(
            value(
                "centre_change_over_scan",
                -c.mu_per_m * span,
                c.mu_err_per_m * span,
                "relative",
                wavelength_nm=wl,
            )
        )
        if r.total is not None:
            out.append(value("total_exponent", r.total.exponent, r.total.exponent_err, "", wavelength_nm=wl))
        if r.pinhole is not None:
            p = r.pinhole
            out.append(value("focal_px", p.focal_px, p.focal_err_px, "px", wavelength_nm=wl))
            k_err = p.focal_err_px * p.source_radius_m
            out.append(value("radius_distance_px_m", p.radius_distance_px_m, k_err, "px m", wavelength_nm=wl))
    return out


def air_scan_document(cal: AirScanCalibration, command: str) -> dict[str, Any]:
    """The ``--json`` result of ``camcal calibrate air-scan``."""
    fits: dict[str, Any] = {}
    warnings: list[str] = []
    for wl, r in sorted(cal.results.items()):
        entry: dict[str, Any] = {"centre": _decay_json(r.centre)}
        if r.total is not None:
            entry["total"] = {"exponent": num(r.total.exponent), "line": line_fit_json(r.total.fit)}
        if r.pinhole is not None:
            entry["pinhole"] = {
                "focal_px": num(r.pinhole.focal_px),
                "focal_stat_err_px": num(r.pinhole.focal_stat_err_px),
                "focal_sys_err_px": num(r.pinhole.focal_sys_err_px),
                "radius_offset_px": HOUGH_RADIUS_SYS_PX,
                "max_rel_residual": num(r.pinhole.max_rel_residual),
                "distance_m": [num(p.distance_m) for p in r.pinhole.points],
                "radius_px": [num(p.value) for p in r.pinhole.points],
                "radius_err_px": [num(p.err) for p in r.pinhole.points],
                "line": line_fit_json(r.pinhole.fit),
            }
        fits[str(wl)] = entry
        warnings += [f"{wl} nm: {n}" for n in r.notes]
    return result_document(
        name="air_scan",
        selection=cal.selection,
        command=command,
        inputs=cal.inputs,
        values=air_scan_values(cal),
        fits=fits,
        frames=cal.frames,
        warnings=warnings,
    )


# ------------------------------------------------------------------ tank scan
@dataclass(frozen=True)
class TankScanResult:
    """One wavelength of a tank scan: the decay in water, in air, and water relative to air."""

    wavelength_nm: int
    water: DecayFit
    air: DecayFit | None
    relative: MediumComparison | None


TankScanCalibration = LabCalibration[int, TankScanResult]


def run_tank_scan(
    folder: Path,
    *,
    camera: str | None = None,
    distance_err_m: float | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> TankScanCalibration:
    """Fit the exponential decay of the centre gray with distance, in water and in air.

    Needs ``distance_m`` and ``medium`` (air or water) for every frame, and
    frames in water at >= 3 distances; the air scan is optional and, when
    present, gives the attenuation relative to air (`compare_media`).
    """
    sel = _scan_rows(folder, "tank-scan", camera, distance_err_m)
    require_column(sel.rows, "medium", "tank-scan", "air or water between source and camera")
    config = FrameConfig(linear_range_gray=tuple(sel.setup.linear_range))  # type: ignore[arg-type]
    frames = map_frames(
        sel.folder, sel.rows, partial(measure_i_center, config), workers=workers, progress=progress
    )
    if not any(f.ok for f in frames):
        raise no_usable_frames("tank-scan", frames)
    wet = [f for f in frames if f.row.medium == "water"]
    if not wet:
        raise CalibrationError("tank-scan needs frames with medium=water; this frame set has only air")
    if not any(f.ok for f in wet):
        raise no_usable_frames("tank-scan", wet, "in water")
    results = {}
    for wl in sorted({f.row.wavelength_nm for f in wet if f.ok}):
        fits: dict[str, DecayFit | None] = {}
        for medium in ("water", "air"):
            good = [f for f in frames if f.ok and f.row.wavelength_nm == wl and f.row.medium == medium]
            if medium == "air" and not good:
                fits[medium] = None
                continue
            try:
                fits[medium] = decay_fit(_points(good, "i_center_gray_per_s", "i_center_err_gray_per_s"))
            except ValueError as exc:
                raise CalibrationError(f"tank-scan at {wl} nm in {medium}: {exc}") from None
        water, dry = fits["water"], fits["air"]
        assert water is not None
        results[wl] = TankScanResult(wl, water, dry, compare_media(water, dry) if dry is not None else None)
    return TankScanCalibration(sel, frames, results, {"distance_err_m": distance_err_m})


def tank_scan_values(cal: TankScanCalibration) -> list[dict[str, Any]]:
    out = []
    for wl, r in sorted(cal.results.items()):
        w = r.water
        out.append(value("mu_per_m", w.mu_per_m, w.mu_err_per_m, "1/m", wavelength_nm=wl, medium="water"))
        out.append(
            value("lambda_att_m", w.lambda_att_m, w.lambda_att_err_m, "m", wavelength_nm=wl, medium="water")
        )
        if r.air is not None and r.relative is not None:
            a, rel = r.air, r.relative
            out.append(value("mu_per_m", a.mu_per_m, a.mu_err_per_m, "1/m", wavelength_nm=wl, medium="air"))
            out.append(
                value(
                    "lambda_att_m",
                    rel.lambda_att_m,
                    rel.lambda_att_err_m,
                    "m",
                    wavelength_nm=wl,
                    medium="water relative to air",
                )
            )
    return out


def tank_scan_document(cal: TankScanCalibration, command: str) -> dict[str, Any]:
    """The ``--json`` result of ``camcal calibrate tank-scan``."""
    fits: dict[str, Any] = {}
    warnings = []
    for wl, r in sorted(cal.results.items()):
        fits[str(wl)] = {"water": _decay_json(r.water)}
        if r.air is not None:
            fits[str(wl)]["air"] = _decay_json(r.air)
            if abs(r.air.mu_per_m) > 3 * r.air.mu_err_per_m:
                warnings.append(
                    f"{wl} nm: the centre gray drifts in air too (mu {r.air.mu_per_m:.3g} ± "
                    f"{r.air.mu_err_per_m:.2g} /m); prefer the value relative to air"
                )
        if not math.isfinite(r.water.lambda_att_m):
            warnings.append(
                f"{wl} nm: no decay in water: λ_att > {r.water.lambda_att_lower_limit_m:.3g} m (95 %)"
            )
    return result_document(
        name="tank_scan",
        selection=cal.selection,
        command=command,
        inputs=cal.inputs,
        values=tank_scan_values(cal),
        fits=fits,
        frames=cal.frames,
        warnings=warnings,
    )
