"""``camcal calibrate psf``: the PSF width from frames of a point-like source (the focus check)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from analysis.calibration import FWHM_PER_SIGMA, PSFResult, fit_point_source, psf_width
from analysis.detect import locate_source
from camcal.calibrate.common import (
    CalibrationError,
    FrameOutcome,
    LabCalibration,
    map_frames,
    no_usable_frames,
    num,
    rejected_outcome,
    result_document,
    select_rows,
    value,
)
from camcal.core.frameset import ManifestRow
from camcal.core.images import read_frame

NAME = "psf"


def _fit(half_size_px: int, max_gray: float, row: ManifestRow, frame: np.ndarray) -> FrameOutcome:
    det = locate_source(frame)
    if not det.found:
        return rejected_outcome(
            row, "no_source", f"no point source above the noise (peak {det.peak_gray:.0f})"
        )
    try:
        fit = fit_point_source(frame, (det.x_px, det.y_px), half_size_px)
    except ValueError as exc:
        return rejected_outcome(row, "off_edge", str(exc))
    if fit.peak_gray > max_gray:
        return rejected_outcome(
            row, "saturated", f"peak {fit.peak_gray:.0f} gray above the linear range (<= {max_gray:g})"
        )
    if max(fit.sigma_x_px, fit.sigma_y_px) > half_size_px / 2.5:
        return rejected_outcome(
            row,
            "no_source",
            f"not point-like: width {fit.sigma_px:.2f} px fills the {fit.window_px} px window (try --window)",
        )
    values = {
        "x_px": fit.x_px,
        "y_px": fit.y_px,
        "sigma_x_px": fit.sigma_x_px,
        "sigma_x_err_px": fit.sigma_x_err_px,
        "sigma_y_px": fit.sigma_y_px,
        "sigma_y_err_px": fit.sigma_y_err_px,
        "flux_gray": fit.flux_gray,
        "peak_gray": fit.peak_gray,
        "chi2_ndof": fit.chi2_ndof,
    }
    return FrameOutcome(row, "ok", values=values)


@dataclass(frozen=True)
class PSFCalibration(LabCalibration[int, PSFResult]):
    """The PSF width per wavelength (`PSFResult`) and each frame's fit.

    ``frame_shape`` is ``(height, width)`` of the frames: the PSF may vary
    over the field, so the plots show it against the distance from the centre.
    """

    frame_shape: tuple[int, int]

    def field_radius_px(self, frame: FrameOutcome) -> float:
        """Distance of a frame's source from the frame centre."""
        cy, cx = (self.frame_shape[0] - 1) / 2.0, (self.frame_shape[1] - 1) / 2.0
        return float(np.hypot(frame.values["x_px"] - cx, frame.values["y_px"] - cy))


def run_psf(
    folder: Path,
    *,
    camera: str | None = None,
    window_px: int = 17,
    max_sigma_px: float | None = None,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> PSFCalibration:
    """Fit the PSF (pixel-integrated Gaussian) in a ``window_px`` square around each frame's source.

    Frames whose brightest pixel leaves the linear range (setup.json) are
    rejected as saturated: a clipped peak would widen the fitted PSF.
    ``max_sigma_px``, if given, is the focus criterion the result is
    checked against (`in_focus`).
    """
    if window_px < 7 or window_px % 2 == 0:
        raise CalibrationError(f"--window must be an odd number of pixels >= 7, got {window_px}")
    if max_sigma_px is not None and max_sigma_px <= 0:
        raise CalibrationError(f"--max-sigma must be > 0, got {max_sigma_px}")
    sel = select_rows(folder, "psf", camera)
    high = float(sel.setup.linear_range[1])
    frames = map_frames(
        sel.folder, sel.rows, partial(_fit, window_px // 2, high), workers=workers, progress=progress
    )
    if not any(f.ok for f in frames):
        raise no_usable_frames("psf", frames)
    results = {}
    for wl in sorted({f.row.wavelength_nm for f in frames if f.ok}):
        v = [f.values for f in frames if f.ok and f.row.wavelength_nm == wl]
        results[wl] = psf_width(
            [x["sigma_x_px"] for x in v],
            [x["sigma_x_err_px"] for x in v],
            [x["sigma_y_px"] for x in v],
            [x["sigma_y_err_px"] for x in v],
        )
    first = next(f for f in frames if f.ok)
    shape = read_frame(sel.folder / first.row.file).shape
    inputs = {"window_px": window_px, "max_sigma_px": max_sigma_px}
    return PSFCalibration(sel, frames, results, inputs, (int(shape[0]), int(shape[1])))


def in_focus(cal: PSFCalibration, wavelength_nm: int) -> bool | None:
    """Whether the PSF meets ``max_sigma_px`` (None when no criterion was given)."""
    limit = cal.inputs.get("max_sigma_px")
    if limit is None:
        return None
    return bool(cal.results[wavelength_nm].sigma.mean <= limit)


def psf_values(cal: PSFCalibration) -> list[dict[str, Any]]:
    out = []
    for wl, r in sorted(cal.results.items()):
        out += [
            value("psf_sigma_px", r.sigma.mean, r.sigma.err, "px", wavelength_nm=wl),
            value("psf_sigma_x_px", r.sigma_x.mean, r.sigma_x.err, "px", wavelength_nm=wl),
            value("psf_sigma_y_px", r.sigma_y.mean, r.sigma_y.err, "px", wavelength_nm=wl),
            value("psf_fwhm_px", r.fwhm_px, r.fwhm_err_px, "px", wavelength_nm=wl),
        ]
    return out


def psf_document(cal: PSFCalibration, command: str) -> dict[str, Any]:
    """The ``--json`` result of ``camcal calibrate psf``."""
    fits: dict[str, Any] = {}
    warnings = []
    for wl, r in sorted(cal.results.items()):
        fits[str(wl)] = {
            "n_frames": r.sigma.n,
            "scatter_px": num(r.sigma.scatter),
            "ellipticity": num(r.ellipticity),
            "fwhm_per_sigma": FWHM_PER_SIGMA,
            "in_focus": in_focus(cal, wl),
        }
        if in_focus(cal, wl) is False:
            warnings.append(
                f"{wl} nm: PSF sigma {r.sigma.mean:.2f} px exceeds "
                f"--max-sigma {cal.inputs['max_sigma_px']:g} px"
            )
        if r.sigma.n == 1:
            warnings.append(f"{wl} nm: one frame only; the error is the fit's, untested by repeats")
    return result_document(
        name=NAME,
        selection=cal.selection,
        command=command,
        inputs=cal.inputs,
        values=psf_values(cal),
        fits=fits,
        frames=cal.frames,
        warnings=warnings,
    )
