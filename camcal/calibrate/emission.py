"""``camcal calibrate emission-ratio``: I0'/I0 per wavelength from images of the LEM's two hemispheres."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from analysis.calibration import DEEP_SEA_TEMPERATURE_C, EmissionRatioResult, HemisphereValue, emission_ratios
from analysis.frame import FrameConfig, analyze_frame
from camcal.calibrate.common import (
    CalibrationError,
    FrameOutcome,
    LabCalibration,
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
from camcal.core.frameset import ManifestRow

NAME = "emission_ratio"


def measure_i_center(config: FrameConfig, row: ManifestRow, frame: np.ndarray) -> FrameOutcome:
    """I_center of a frame, also per second at 0 dB (``i_center_gray_per_s``) for comparing settings."""
    a = analyze_frame(frame, config)
    if not a.ok:
        return rejected_outcome(row, a.reason or "rejected", a.detail, center_gray=a.center_gray)
    norm = normalisation(row)
    return FrameOutcome(
        row,
        "ok",
        values={
            "i_center_gray": a.i_center_gray,
            "i_center_err_gray": a.i_center_err_gray,
            "i_center_gray_per_s": a.i_center_gray / norm,  # type: ignore[operator]
            "i_center_err_gray_per_s": a.i_center_err_gray / norm,  # type: ignore[operator]
            "background_gray": a.background_gray,
            "radius_px": a.radius_px,
        },
    )


#: I0'/I0 of each wavelength (`EmissionRatioResult`), from one camera's frames.
EmissionRatioCalibration = LabCalibration[int, EmissionRatioResult]


def run_emission_ratio(
    folder: Path,
    *,
    camera: str | None = None,
    temperature_tolerance_c: float = 2.0,
    temperature_c: float = DEEP_SEA_TEMPERATURE_C,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> EmissionRatioCalibration:
    """Measure I_center on every frame and form far/near ratios per wavelength and temperature run.

    Needs the ``hemisphere`` column (near/far). Frames are compared per
    second at 0 dB, so both hemispheres may be taken at different settings
    as long as both stay in the linear range (from setup.json). The ratio
    is given at ``temperature_c`` (default: the deep sea), from a line
    through the temperature runs.
    """
    if temperature_tolerance_c <= 0:
        raise CalibrationError(f"--temperature-tolerance must be > 0, got {temperature_tolerance_c}")
    sel = select_rows(folder, "emission-ratio", camera)
    require_column(sel.rows, "hemisphere", "emission-ratio", "which LEM side faces the camera: near or far")
    config = FrameConfig(linear_range_gray=tuple(sel.setup.linear_range))  # type: ignore[arg-type]
    frames = map_frames(
        sel.folder, sel.rows, partial(measure_i_center, config), workers=workers, progress=progress
    )
    good = [f for f in frames if f.ok]
    if not good:
        raise no_usable_frames("emission-ratio", frames)
    values = [
        HemisphereValue(
            f.row.wavelength_nm,
            f.row.hemisphere,  # type: ignore[arg-type]
            f.row.temperature_c,
            f.values["i_center_gray_per_s"],
            f.values["i_center_err_gray_per_s"],
        )
        for f in good
    ]
    try:
        results = emission_ratios(values, temperature_tolerance_c, temperature_c)
    except ValueError as exc:
        raise CalibrationError(f"emission-ratio: {exc}") from None
    inputs = {"temperature_tolerance_c": temperature_tolerance_c, "temperature_c": temperature_c}
    return EmissionRatioCalibration(sel, frames, results, inputs)


def emission_values(cal: EmissionRatioCalibration) -> list[dict[str, Any]]:
    """The calibrated values: I0'/I0 per wavelength, per temperature run, and the temperature effect."""
    out = []
    for wl, r in sorted(cal.results.items()):
        t = num(r.temperature_c, 4)
        out.append(value("emission_ratio", r.ratio, r.ratio_err, "", wavelength_nm=wl, temperature_c=t))
        if r.ratio_per_c is not None:
            out.append(value("ratio_per_c", r.ratio_per_c, r.ratio_per_c_err, "1/°C", wavelength_nm=wl))
        for run in r.runs:
            out.append(
                value(
                    "emission_ratio_at_temperature",
                    run.ratio,
                    run.ratio_err,
                    "",
                    wavelength_nm=wl,
                    temperature_c=num(run.temperature_c, 4),
                )
            )
        e = r.temperature_effect
        if e is not None:
            ctx = {"wavelength_nm": wl, "cold_c": num(e.cold_c, 4), "warm_c": num(e.warm_c, 4)}
            out.append(value("ratio_change", e.ratio_change, e.ratio_change_err, "relative", **ctx))
            out.append(
                value("brightness_change", e.brightness_change, e.brightness_change_err, "relative", **ctx)
            )
    return out


def emission_document(cal: EmissionRatioCalibration, command: str) -> dict[str, Any]:
    """The ``--json`` result of ``camcal calibrate emission-ratio``."""
    fits: dict[str, Any] = {}
    warnings = []
    for wl, r in sorted(cal.results.items()):
        fits[str(wl)] = {
            "runs": [
                {
                    "temperature_c": num(run.temperature_c, 4),
                    "temperature_spread_c": num(run.temperature_spread_c, 3),
                    "near_gray_per_s": num(run.near.mean),
                    "near_err_gray_per_s": num(run.near.err),
                    "n_near": run.near.n,
                    "far_gray_per_s": num(run.far.mean),
                    "far_err_gray_per_s": num(run.far.err),
                    "n_far": run.far.n,
                    "ratio": num(run.ratio),
                    "ratio_err": num(run.ratio_err),
                }
                for run in r.runs
            ],
            "temperature_c": num(r.temperature_c, 4),
            "ratio": num(r.ratio),
            "ratio_err": num(r.ratio_err),
        }
        e = r.temperature_effect
        if e is not None and abs(e.ratio_change) > 0.01:
            warnings.append(
                f"{wl} nm: I0'/I0 moved by {100 * e.ratio_change:+.2f} % from {e.cold_c:.1f} to "
                f"{e.warm_c:.1f} °C (T-REX: < 1 %)"
            )
        if r.temperature_c is None:
            warnings.append(
                f"{wl} nm: frames carry no temperature_c; the ratio holds at the lab's temperature"
            )
    ratios = {
        str(wl): {"value": num(r.ratio, 5), "err": num(r.ratio_err, 3)}
        for wl, r in sorted(cal.results.items())
    }
    return result_document(
        name=NAME,
        selection=cal.selection,
        command=command,
        inputs=cal.inputs,
        values=emission_values(cal),
        fits=fits,
        frames=cal.frames,
        setup={"emission_ratio": ratios},
        warnings=warnings,
    )
