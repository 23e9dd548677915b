"""``camcal calibrate linearity``: the linear response range from darkroom sweeps.

Two passes over the frames: the first finds the steady source in every
frame where it shows, the second reads the mean gray of the same pixels
(at the median position) in every frame, dim and saturated alike.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from analysis.calibration import ResponseCurve, combine_repeats, gray_at, response_linearity
from analysis.detect import locate_source
from analysis.linearity import gain_factor
from analysis.profile import DEFAULT_CENTER_PIXELS
from camcal.calibrate.common import (
    CalibrationError,
    FrameOutcome,
    LabCalibration,
    line_fit_json,
    map_frames,
    no_usable_frames,
    num,
    result_document,
    select_rows,
    value,
)
from camcal.core.frameset import ManifestRow

NAME = "linearity"
SWEEP_UNITS = {"exposure": ("s", "gray/s"), "gain": ("gain factor", "gray per unit gain")}


def _locate(row: ManifestRow, frame: np.ndarray) -> FrameOutcome:
    det = locate_source(frame)
    if not det.found:
        return FrameOutcome(row, "ok", values={"source_found": False})
    return FrameOutcome(row, "ok", values={"source_found": True, "x_px": det.x_px, "y_px": det.y_px})


def _gray(
    position: dict[int, tuple[float, float]], n_pixels: int, row: ManifestRow, frame: np.ndarray
) -> FrameOutcome:
    pos = position.get(row.wavelength_nm)
    if pos is None:
        return FrameOutcome(
            row, "rejected", "no_source", f"source found in no frame of {row.wavelength_nm} nm"
        )
    c = gray_at(frame, pos, n_pixels)
    return FrameOutcome(row, "ok", values={"center_gray": c.mean_gray, "center_err_gray": c.err_gray})


@dataclass(frozen=True)
class LinearityCalibration(LabCalibration[tuple[int, str], ResponseCurve]):
    """The response sweeps of one camera, per wavelength.

    ``curves`` maps ``(wavelength_nm, sweep)`` to the fitted `ResponseCurve`;
    ``positions`` the pixel position (x, y) read in every frame of a wavelength.
    """

    positions: dict[int, tuple[float, float]]

    @property
    def curves(self) -> dict[tuple[int, str], ResponseCurve]:
        return self.results

    @property
    def linear_range_gray(self) -> tuple[float, float]:
        """The recommended range: from the lowest gray any sweep shows linear to the lowest high end.

        A sweep's low end is often just its dimmest setting, so the lowest
        one is the best evidence there; at the top the sensor compresses,
        so the most cautious high end is kept.
        """
        lows = [c.linear_range_gray[0] for c in self.curves.values()]
        highs = [c.linear_range_gray[1] for c in self.curves.values()]
        return min(lows), min(highs)


def _sweeps(
    points: dict[tuple[float, float], tuple[float, float, int]],
) -> dict[str, tuple[float, list[Any]]]:
    """The exposure sweep (the gain with most exposures) and gain sweep (the exposure with most gains)."""
    by_gain: dict[float, list[tuple[float, float, float, int]]] = defaultdict(list)
    by_exposure: dict[float, list[tuple[float, float, float, int]]] = defaultdict(list)
    for (exposure, gain), (g, e, n) in points.items():
        by_gain[gain].append((exposure, g, e, n))
        by_exposure[exposure].append((float(gain_factor(gain)), g, e, n))
    out: dict[str, tuple[float, list[Any]]] = {}
    for sweep, groups in (("exposure", by_gain), ("gain", by_exposure)):
        fixed, pts = max(groups.items(), key=lambda kv: (len(kv[1]), -kv[0]))
        if len(pts) >= 3:
            out[sweep] = (fixed, sorted(pts))
    return out


def run_linearity(
    folder: Path,
    *,
    camera: str | None = None,
    tolerance: float = 0.01,
    n_sigma: float = 3.0,
    center_pixels: int = DEFAULT_CENTER_PIXELS,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> LinearityCalibration:
    """Fit the exposure and gain sweeps of each wavelength in a darkroom frame set.

    Frames are grouped by setting (exposure, gain); the repeats of a
    setting are averaged (`combine_repeats`). The exposure sweep is the
    gain with the most exposures, the gain sweep the exposure with the most
    gains; each needs three settings. See `response_linearity` for the fit.
    """
    if not (0 < tolerance < 1):
        raise CalibrationError(f"--tolerance must lie in (0, 1), got {tolerance}")
    sel = select_rows(folder, "linearity", camera)
    located = map_frames(sel.folder, sel.rows, _locate, workers=workers, progress=progress)
    if not any(f.ok for f in located):
        raise no_usable_frames("linearity", located)
    xy: dict[int, list[tuple[float, float]]] = defaultdict(list)
    for f in located:
        if f.ok and f.values.get("source_found"):
            xy[f.row.wavelength_nm].append((f.values["x_px"], f.values["y_px"]))
    if not xy:
        raise CalibrationError("linearity: the source stands out in no frame; is it on and in view?")
    positions = {
        wl: (float(np.median([p[0] for p in v])), float(np.median([p[1] for p in v]))) for wl, v in xy.items()
    }
    frames = map_frames(
        sel.folder, sel.rows, partial(_gray, positions, center_pixels), workers=workers, progress=progress
    )

    curves: dict[tuple[int, str], ResponseCurve] = {}
    for wl in sorted(positions):
        settings: dict[tuple[float, float], list[FrameOutcome]] = defaultdict(list)
        for f in frames:
            if f.ok and f.row.wavelength_nm == wl:
                settings[(f.row.exposure_s, f.row.gain_db)].append(f)
        points = {}
        for key, fs in settings.items():
            c = combine_repeats(
                [f.values["center_gray"] for f in fs], [f.values["center_err_gray"] for f in fs]
            )
            points[key] = (c.mean, c.err, c.n)
        for sweep, (fixed, pts) in _sweeps(points).items():
            x, g, e, n = (list(v) for v in zip(*pts, strict=True))
            try:
                curves[(wl, sweep)] = response_linearity(
                    x, g, e, sweep=sweep, fixed=fixed, n_frames=n, tolerance=tolerance, n_sigma=n_sigma
                )
            except ValueError as exc:
                raise CalibrationError(f"linearity at {wl} nm: {exc}") from None
    if not curves:
        raise CalibrationError(
            "linearity needs >= 3 exposures at one gain or >= 3 gains at one exposure, for one wavelength"
        )
    inputs = {"tolerance": tolerance, "n_sigma": n_sigma, "center_pixels": center_pixels}
    return LinearityCalibration(sel, frames, curves, inputs, positions)


def linearity_values(cal: LinearityCalibration) -> list[dict[str, Any]]:
    """The calibrated values, one per quantity, sweep and wavelength."""
    out = []
    for (wl, sweep), c in sorted(cal.curves.items()):
        ctx = {"wavelength_nm": wl, "sweep": sweep, "fixed": num(c.fixed)}
        unit = SWEEP_UNITS[sweep][1]
        out += [
            value("slope", c.fit.slope, c.fit.slope_err, unit, **ctx),
            value("dark_level_gray", c.fit.intercept, c.fit.intercept_err, "gray", **ctx),
            value("r2", c.fit.r2, None, "", **ctx),
            value("departure_gray", c.departure_gray, c.departure_err_gray, "gray", **ctx),
            value("linear_low_gray", c.linear_range_gray[0], None, "gray", **ctx),
            value("linear_high_gray", c.linear_range_gray[1], None, "gray", **ctx),
        ]
    return out


def linearity_document(cal: LinearityCalibration, command: str) -> dict[str, Any]:
    """The ``--json`` result of ``camcal calibrate linearity``."""
    fits = {}
    for (wl, sweep), c in sorted(cal.curves.items()):
        fits[f"{wl}/{sweep}"] = {
            "wavelength_nm": wl,
            "sweep": sweep,
            "x_unit": SWEEP_UNITS[sweep][0],
            "fixed": num(c.fixed),
            "position_px": [num(v) for v in cal.positions[wl]],
            "x": [num(v) for v in c.x],
            "gray": [num(v) for v in c.gray],
            "gray_err": [num(v) for v in c.gray_err],
            "n_frames": list(c.n_frames),
            "linear": list(c.linear),
            "fitted": list(c.fitted),
            "relative_residuals": [num(v) for v in c.relative_residuals],
            "departure_x": num(c.departure_x),
            "line": line_fit_json(c.fit),
        }
    lo, hi = cal.linear_range_gray
    warnings = [
        f"{wl} nm {sweep} sweep never leaves linearity: the departure lies above {c.gray[-1]:.1f} gray"
        for (wl, sweep), c in sorted(cal.curves.items())
        if c.departure_gray is None
    ]
    return result_document(
        name=NAME,
        selection=cal.selection,
        command=command,
        inputs=cal.inputs,
        values=linearity_values(cal),
        fits=fits,
        frames=cal.frames,
        setup={"linear_range": [math.ceil(lo * 10) / 10, math.floor(hi * 10) / 10]},
        warnings=warnings,
    )
