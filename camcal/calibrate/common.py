"""What every lab calibration shares: choosing rows, reading frames in parallel, the JSON result.

The JSON result of every ``camcal calibrate`` subcommand has one envelope,
built by `result_document`, so that a calibration record (name, version,
source command and frame set, values with errors) can be made from any of
them: see docs/calibration.md.
"""

from __future__ import annotations

import hashlib
import os
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Generic, TypeVar

import cv2
import numpy as np

from analysis import REASON_HELP
from analysis.linearity import gain_factor
from camcal.core import __version__
from camcal.core.frameset import MANIFEST, SETUP, ManifestRow, Setup, read_manifest, read_setup
from camcal.core.images import FrameReadError, read_frame

#: Version of the JSON result document; bump it when a field changes meaning.
SCHEMA = "camcal.calibration/1"


class CalibrationError(Exception):
    """A calibration cannot run on this frame set (a missing column, too few distances, no usable frame).

    Fatal for the command: it exits with status 2 and this one-line message.
    """


@dataclass(frozen=True)
class FrameOutcome:
    """One manifest row after the per-frame step of a calibration.

    ``status`` is ``ok`` or ``rejected`` with a frame-set ``reason`` word
    (docs/conventions.md) and a human ``detail``; ``values`` holds what was
    measured on the frame, by name with its unit in the name.
    """

    row: ManifestRow
    status: str
    reason: str | None = None
    detail: str | None = None
    values: Mapping[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def rejected_outcome(row: ManifestRow, reason: str, detail: str | None, **values: Any) -> FrameOutcome:
    return FrameOutcome(row, "rejected", str(reason), detail, values)


@dataclass(frozen=True)
class Selection:
    """The rows of the one camera a calibration looks at, and the frame set's setup."""

    folder: Path
    camera: str
    rows: list[ManifestRow]
    setup: Setup


K = TypeVar("K")
R = TypeVar("R")


@dataclass(frozen=True)
class LabCalibration(Generic[K, R]):
    """What a lab calibration found: the frames it read (``selection``), each frame's outcome,
    the results per key (a wavelength, or a wavelength and a sweep) and the inputs it ran with.

    Every experiment returns one (`camcal.calibrate.EXPERIMENTS`); a few add what their plots need.
    """

    selection: Selection
    frames: list[FrameOutcome]
    results: dict[K, R]
    inputs: dict[str, Any]


def select_rows(folder: Path, command: str, camera: str | None = None) -> Selection:
    """Read the manifest and setup, and keep the rows of one camera.

    A lab frame set normally holds one camera; with several, ``camera``
    must name one. Raises `CalibrationError` (or `camcal.core.frameset.FrameSetError`
    for an unreadable set) with a one-line message.
    """
    folder = Path(folder)
    rows = read_manifest(folder)
    setup = read_setup(folder)
    if not rows:
        raise CalibrationError(f"{folder / MANIFEST}: lists no frames")
    cameras = sorted({r.camera for r in rows if r.camera})
    if camera is None:
        if len(cameras) > 1:
            raise CalibrationError(
                f"{command}: the frame set holds cameras {', '.join(cameras)}; choose one with --camera"
            )
        camera = cameras[0] if cameras else ""
    elif camera not in cameras:
        raise CalibrationError(f"--camera: no frames of camera {camera!r} (have {', '.join(cameras)})")
    return Selection(folder, camera, [r for r in rows if r.camera == camera], setup)


def require_column(rows: Sequence[ManifestRow], column: str, command: str, why: str) -> None:
    """Raise `CalibrationError` unless every usable row has a value in ``column``."""
    usable = [r for r in rows if not r.error]
    missing = [r for r in usable if getattr(r, column) is None]
    if not missing:
        return
    if len(missing) == len(usable):
        raise CalibrationError(
            f"{command} needs a {column} column in manifest.csv ({why}); "
            f"this frame set has no {column} values"
        )
    raise CalibrationError(
        f"{command} needs {column} for every frame ({why}); {len(missing)} of {len(usable)} rows "
        f"lack it, the first is {missing[0].file}"
    )


def normalisation(row: ManifestRow) -> float:
    """Exposure times linear gain: dividing a gray by it gives gray per second at 0 dB."""
    return float(row.exposure_s * gain_factor(row.gain_db))


FrameFunc = Callable[[ManifestRow, np.ndarray], FrameOutcome]


def _load_and_run(args: tuple[str, ManifestRow, FrameFunc]) -> FrameOutcome:
    folder, row, func = args
    if row.error:
        return rejected_outcome(row, "bad_metadata", row.error)
    try:
        frame = read_frame(Path(folder) / row.file)
    except FrameReadError as exc:
        return rejected_outcome(row, exc.reason, exc.detail)
    return func(row, frame)


def _init_worker() -> None:
    cv2.setNumThreads(1)


def map_frames(
    folder: Path,
    rows: Sequence[ManifestRow],
    func: FrameFunc,
    *,
    workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> list[FrameOutcome]:
    """Read each row's frame and apply ``func`` (a picklable top-level function), in row order.

    Rows with bad metadata and unreadable files become rejected outcomes
    without calling ``func``. Large sets are spread over ``workers``
    processes (default: all cores); small ones run in this process.
    """
    jobs = [(str(folder), row, func) for row in rows]
    workers = workers or os.cpu_count() or 1
    out: list[FrameOutcome] = []
    if workers <= 1 or len(jobs) < 16:
        for job in jobs:
            out.append(_load_and_run(job))
            if progress:
                progress(len(out), len(jobs))
        return out
    with ProcessPoolExecutor(max_workers=workers, initializer=_init_worker) as pool:
        for outcome in pool.map(_load_and_run, jobs, chunksize=4):
            out.append(outcome)
            if progress:
                progress(len(out), len(jobs))
    return out


def reason_counts(frames: Iterable[FrameOutcome]) -> Counter[str]:
    """Frames by status: ``ok`` or the rejection reason."""
    return Counter("ok" if f.ok else (f.reason or "rejected") for f in frames)


def no_usable_frames(command: str, frames: Sequence[FrameOutcome], what: str = "") -> CalibrationError:
    """The error for a set where no frame survived, naming the commonest reason and its remedy."""
    counts = reason_counts(frames)
    counts.pop("ok", None)
    parts = ", ".join(f"{n} {r}" for r, n in counts.most_common())
    top = counts.most_common(1)[0][0] if counts else None
    hint = f" ({REASON_HELP[top]})" if top in REASON_HELP else ""
    scope = f" {what}" if what else ""
    return CalibrationError(f"{command}: no usable frame{scope}: all {len(frames)} rejected: {parts}{hint}")


def _sha256(path: Path) -> str | None:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else None


def frame_set_fingerprint(folder: Path, n_rows: int) -> dict[str, Any]:
    """Where the frames came from: the folder and hashes of its manifest and setup.

    The images are not hashed (a dive's set holds gigabytes); the manifest
    names every file, so its hash identifies the set's content as listed.
    """
    folder = Path(folder)
    return {
        "path": str(folder.resolve()),
        "manifest_sha256": _sha256(folder / MANIFEST),
        "setup_sha256": _sha256(folder / SETUP),
        "n_rows": n_rows,
    }


def num(x: float | None, digits: int = 6) -> float | None:
    """A JSON-ready float: rounded to ``digits`` significant digits, None if missing or not finite."""
    if x is None:
        return None
    x = float(x)
    if not np.isfinite(x):
        return None
    return float(f"{x:.{digits}g}")


def value(quantity: str, val: float | None, err: float | None, unit: str, **context: Any) -> dict[str, Any]:
    """One calibrated value: ``quantity``, ``value``, ``err`` (one sigma or None), ``unit``, and its context.

    Context keys say what the value belongs to (``wavelength_nm``,
    ``sweep``, ``temperature_c``, ``medium``); a calibration record stores
    one row per value.
    """
    return {"quantity": quantity, "value": num(val), "err": num(err), "unit": unit, **context}


def frame_entries(frames: Sequence[FrameOutcome]) -> list[dict[str, Any]]:
    """The per-frame part of the result, in manifest order."""
    out = []
    for f in frames:
        entry: dict[str, Any] = {
            "file": f.row.file,
            "wavelength_nm": f.row.wavelength_nm or None,
            "exposure_s": num(f.row.exposure_s),
            "gain_db": num(f.row.gain_db),
            "distance_m": num(f.row.distance_m),
            "status": f.status,
            "reason": f.reason,
            "detail": f.detail,
        }
        entry.update({k: (num(v) if isinstance(v, float) else v) for k, v in f.values.items()})
        out.append(entry)
    return out


def result_document(
    *,
    name: str,
    selection: Selection,
    command: str,
    inputs: Mapping[str, Any],
    values: list[dict[str, Any]],
    fits: Mapping[str, Any],
    frames: Sequence[FrameOutcome],
    setup: Mapping[str, Any] | None = None,
    warnings: Sequence[str] = (),
) -> dict[str, Any]:
    """The JSON result of a calibration (schema `SCHEMA`, fields in docs/calibration.md)."""
    return {
        "schema": SCHEMA,
        "name": name,
        "created_utc": datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z"),
        "source": {
            "command": command,
            "frame_set": frame_set_fingerprint(selection.folder, len(selection.rows)),
        },
        "software": {"name": "camcal", "version": __version__},
        "camera": selection.camera,
        "inputs": dict(inputs),
        "values": values,
        "setup": dict(setup or {}),
        "fits": dict(fits),
        "summary": dict(reason_counts(frames)),
        "warnings": list(warnings),
        "frames": frame_entries(frames),
    }


def line_fit_json(fit: Any) -> dict[str, Any]:
    """A `analysis.calibration.fit.LineFit` as JSON: parameters, chi2, points and residuals."""
    return {
        "slope": num(fit.slope),
        "slope_err": num(fit.slope_err),
        "intercept": num(fit.intercept),
        "intercept_err": num(fit.intercept_err),
        "chi2": num(fit.chi2),
        "ndof": fit.ndof,
        "error_scale": num(fit.error_scale),
        "r2": num(fit.r2, 8),
        "x": [num(v) for v in fit.x],
        "y": [num(v) for v in fit.y],
        "y_err": [num(v) for v in fit.y_err],
        "x_err": [num(v) for v in fit.x_err],
        "residuals": [num(v) for v in fit.residuals],
    }
