"""Simulated lab frame sets for the calibrations of the camera system, with their truth.

One spec class per experiment of the paper's "Calibration" section
(`darkroom`: linearity, emission ratio, PSF; `scans`: air and tank); each
plans its frames (`shots`), renders one (`render`) and states what an
analysis should recover (`truth`). `write_lab_set` turns any of them into a
frame set (manifest.csv with the per-frame columns of docs/frameset.md,
setup.json, PNGs) and a truth.json beside it.

Measured quantities that the lab reads off a scale or a thermometer (the
distance, the temperature) are drawn around their true values with the
stated reading error, so the manifest holds readings and truth.json the
true values; the analysis must carry those errors to be right.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import asdict
from datetime import timedelta
from pathlib import Path
from typing import Any

import numpy as np

from camcal.core.calibrations import LAB_EXPERIMENTS
from camcal.core.files import write_atomic
from camcal.core.frameset import MANIFEST, ManifestRow, Setup
from camcal.core.framewriter import FrameSetWriter
from lrm.labset.base import LabBase, LabShot
from lrm.labset.darkroom import LINEARITY_EXPOSURES_S, EmissionRatioLab, LinearityLab, PSFLab
from lrm.labset.scans import AirScanLab, TankScanLab

TRUTH = "truth.json"
LAB_KINDS = LAB_EXPERIMENTS  # the experiments this simulator renders: all of them

__all__ = [
    "LAB_KINDS",
    "LINEARITY_EXPOSURES_S",
    "SPEC_CLASSES",
    "TRUTH",
    "AirScanLab",
    "EmissionRatioLab",
    "LabBase",
    "LabShot",
    "LinearityLab",
    "PSFLab",
    "TankScanLab",
    "lab_spec",
    "match_truth",
    "truth_values",
    "write_lab_set",
]


SPEC_CLASSES: dict[str, type[LabBase]] = {
    c.kind: c for c in (LinearityLab, EmissionRatioLab, AirScanLab, TankScanLab, PSFLab)
}
assert tuple(SPEC_CLASSES) == LAB_EXPERIMENTS, "a lab experiment without its simulation"


def lab_spec(kind: str, **values: Any) -> LabBase:
    """The spec of one lab experiment by its kind name, with ``values`` replacing defaults."""
    try:
        cls = SPEC_CLASSES[kind]
    except KeyError:
        raise ValueError(f"unknown lab kind {kind!r}; choose from {', '.join(LAB_KINDS)}") from None
    unknown = sorted(set(values) - set(cls.__dataclass_fields__))
    if unknown:
        raise ValueError(f"{kind} has no setting {', '.join(unknown)}")
    return cls(**values)


def _row(spec: LabBase, shot: LabShot) -> ManifestRow:
    when = spec.start + timedelta(seconds=shot.index)
    return ManifestRow(
        index=shot.index,
        file=f"{spec.camera_id}_{shot.index + 1:05d}.png",
        camera=spec.camera_id,
        wavelength_nm=shot.wavelength_nm,
        exposure_s=shot.exposure_s,
        gain_db=shot.gain_db,
        timestamp=when.isoformat().replace("+00:00", "Z"),
        seq=shot.index + 1,
        distance_m=shot.distance_m,
        distance_err_m=shot.distance_err_m,
        temperature_c=shot.temperature_c,
        medium=shot.medium,
        hemisphere=shot.hemisphere,
    )


def write_lab_set(
    out: Path, spec: LabBase, *, progress: Callable[[int, int], None] | None = None
) -> dict[str, Any]:
    """Render ``spec`` into the frame set ``out`` and write its truth.json; return the truth.

    Each frame's noise comes from ``(seed, frame index)``, so a set is the
    same on every run. ``out`` must not hold a frame set already.
    """
    out = Path(out)
    if (out / MANIFEST).exists():
        raise FileExistsError(f"{out} already holds a frame set; choose an empty folder")
    shots = spec.shots()
    frames: list[dict[str, Any]] = []
    cache: dict[Any, Any] = {}
    with FrameSetWriter(out, Setup()) as writer:
        for shot in shots:
            frame, truth = spec.render(shot, np.random.default_rng([spec.seed, shot.index]), cache)
            row = writer.add(frame, _row(spec, shot))
            # The shot's readings last: the manifest's distance, not the renderer's true one.
            frames.append({"file": row.file, **truth, **asdict(shot)})
            if progress:
                progress(len(frames), len(shots))
    doc = {
        "kind": spec.kind,
        "seed": spec.seed,
        "camera_model": {**asdict(spec.camera), "focal_px": spec.camera.focal_px},
        "truth": spec.truth(shots),
        "frames": frames,
    }
    write_atomic(out / TRUTH, (json.dumps(doc, indent=1, default=str) + "\n").encode(), fsync=False)
    return doc


def truth_values(doc: dict[str, Any]) -> list[dict[str, Any]]:
    """The true values of a lab set, in the form of a calibration result's ``values``.

    Each entry has ``quantity`` and ``value`` plus the context keys the
    matching result value carries (``wavelength_nm``, ``sweep``,
    ``medium``), so a result can be checked entry by entry (`match_truth`).
    Only quantities the simulator knows exactly are listed.
    """
    kind, t = doc["kind"], doc["truth"]
    out: list[dict[str, Any]] = []

    def add(quantity: str, val: float, **context: Any) -> None:
        out.append({"quantity": quantity, "value": float(val), **context})

    if kind == "linearity":
        wl = t["wavelength_nm"]
        e, g = t["exposure_sweep"], t["gain_sweep"]
        add("slope", e["slope_gray_per_s"], wavelength_nm=wl, sweep="exposure")
        add("dark_level_gray", e["intercept_gray"], wavelength_nm=wl, sweep="exposure")
        add("departure_gray", e["departure_gray"], wavelength_nm=wl, sweep="exposure")
        add("slope", g["slope_gray_per_gain"], wavelength_nm=wl, sweep="gain")
        add("dark_level_gray", g["intercept_gray"], wavelength_nm=wl, sweep="gain")
        add("departure_gray", g["departure_gray"], wavelength_nm=wl, sweep="gain")
    elif kind == "emission-ratio":
        for wl, r in t["emission_ratio"].items():
            runs = sorted(r["runs"], key=lambda x: x["temperature_c"])
            add("emission_ratio", r["at_reference"], wavelength_nm=int(wl))
            if len(runs) >= 2:
                slope = (runs[-1]["ratio"] - runs[0]["ratio"]) / (
                    runs[-1]["temperature_c"] - runs[0]["temperature_c"]
                )
                add("ratio_per_c", slope, wavelength_nm=int(wl))
                add("ratio_change", r["ratio_change"], wavelength_nm=int(wl))
                add("brightness_change", r["brightness_change"], wavelength_nm=int(wl))
    elif kind == "air-scan":
        for wl, w in t["wavelengths"].items():
            add("centre_mu_per_m", w["mu_per_m"], wavelength_nm=int(wl))
            add("total_exponent", t["exponent"], wavelength_nm=int(wl))
            add("focal_px", t["focal_px"], wavelength_nm=int(wl))
    elif kind == "tank-scan":
        for wl, w in t["wavelengths"].items():
            add("mu_per_m", w["mu_water_per_m"], wavelength_nm=int(wl), medium="water")
            add("lambda_att_m", w["lambda_att_m"], wavelength_nm=int(wl), medium="water")
            add("mu_per_m", w["mu_air_per_m"], wavelength_nm=int(wl), medium="air")
            relative = 1.0 / (w["mu_water_per_m"] - w["mu_air_per_m"])
            add("lambda_att_m", relative, wavelength_nm=int(wl), medium="water relative to air")
    elif kind == "psf":
        wl, sigma = t["wavelength_nm"], t["psf_sigma_px"]
        for q in ("psf_sigma_px", "psf_sigma_x_px", "psf_sigma_y_px"):
            add(q, sigma, wavelength_nm=wl)
        add("psf_fwhm_px", 2.0 * math.sqrt(2.0 * math.log(2.0)) * sigma, wavelength_nm=wl)
    else:
        raise ValueError(f"unknown lab kind {kind!r} in the truth document")
    return out


_MATCH_KEYS = ("quantity", "wavelength_nm", "sweep", "medium")


def match_truth(
    values: list[dict[str, Any]], truth: list[dict[str, Any]]
) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    """Pairs (result value, true value) that agree on quantity, wavelength, sweep and medium.

    Raises `ValueError` naming a true value with no measured counterpart,
    so a result that silently drops a quantity does not pass a check.
    """
    pairs = []
    for tv in truth:
        key = tuple(tv.get(k) for k in _MATCH_KEYS)
        found = [v for v in values if tuple(v.get(k) for k in _MATCH_KEYS) == key]
        if len(found) != 1:
            raise ValueError(
                f"{len(found)} result values match the true {dict(zip(_MATCH_KEYS, key, strict=True))}"
            )
        pairs.append((found[0], tv))
    return pairs
