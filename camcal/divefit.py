"""λ_abs and λ_sca of a stored dive: the χ² fit on the frames the store holds (``camcal fit --dive``).

The same fit as for a frame-set folder (`camcal.fitset`), fed from the
store: the dive's frames over a span (by default the station, frames within
50 m of the deepest, as the API's λ_att table), their files under the data
folder, and the calibration inputs of an analysis run (by default the live
one; ``analysis_runs.calibration`` holds a setup.json dict) or of a chosen
calibration record. The result can be kept in the store (table
``chisq_fits``) for the report and the API.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from analysis.chisq import FitInputError
from camcal.core import __version__
from camcal.core.calibrations import setup_of
from camcal.core.frameset import FrameSetError, ManifestRow, Setup
from camcal.fitdoc import to_json
from camcal.fitset import FitOptions, FolderFit, fit_analysis
from camcal.pipeline import Overrides, analyze_rows
from ingest.spans import Span
from storage import queries
from storage.files import UnsafePath
from storage.store import Store


class DiveLookupError(LookupError):
    """The dive, its run or the calibration asked for is not in the store."""


@dataclass(frozen=True)
class DiveInputs:
    """What a dive's fit is built from: the frames of the span and the calibration inputs.

    ``run`` is the analysis run whose frames and calibration are used (as
    `storage.queries.runs` lists it), ``calibration`` the calibration
    record in force (None: the run's own setup, or T-REX values), ``span``
    the span as applied (`ingest.spans.Span.select`).
    """

    dive: dict[str, Any]
    run: dict[str, Any]
    setup: Setup
    calibration: dict[str, Any] | None
    span: dict[str, Any]
    rows: list[ManifestRow] = field(repr=False)
    data_root: Path


@dataclass(frozen=True)
class DiveFit:
    """A dive's χ² fits and the inputs they came from."""

    inputs: DiveInputs
    fit: FolderFit = field(repr=False)


def pick_run(store: Store, dive_id: int, run_id: int | None = None) -> dict[str, Any]:
    """The dive's live run (else its newest), or run ``run_id`` of the dive (`queries.chosen_run`)."""
    try:
        return store.call(queries.chosen_run, dive_id, run_id)
    except queries.RunLookupError as exc:
        raise DiveLookupError(str(exc)) from None


def run_calibration(
    store: Store, dive_id: int, run: dict[str, Any], calibration: str | None = None
) -> tuple[Setup, dict[str, Any] | None]:
    """The setup in force for a run of the dive, and the calibration record it came from (if any).

    The run's own inputs (`storage.queries.calibration_in_force`: an imported dive's setup.json
    for its live run); ``calibration`` (an id, ``name`` or ``name@version``) replaces them with
    that record's.
    """
    if calibration is not None:
        record = store.call(queries.calibration, calibration)
        if record is None:
            raise DiveLookupError(f"no calibration {calibration!r} (try `camcal calibration list`)")
        return setup_of(record), record
    setup = store.call(queries.setup_in_force, dive_id, run)
    record = store.call(queries.calibration, run["calibration_id"]) if run.get("calibration_id") else None
    return setup, record


def dive_inputs(
    store: Store,
    dive_name: str,
    *,
    run_id: int | None = None,
    calibration: str | None = None,
    span: Span | None = None,
    overrides: Overrides | None = None,
) -> DiveInputs:
    """The frames of a dive over a span (default: the station) as frame-set rows, and the setup.

    Raises `DiveLookupError` for an unknown dive, run or calibration and
    `FitInputError` when the span holds no frame.
    """
    dive_row = store.call(queries.dive_by_name, dive_name)
    if dive_row is None:
        with store.read() as s:
            names = [d["name"] for d in queries.dives(s)]
        known = ", ".join(names[:5]) or "none"
        raise DiveLookupError(f"no dive named {dive_name!r} (dives in the store: {known})")
    with store.read() as s:
        dive = queries.dive_record(s, dive_row.id)
    assert dive is not None
    run = pick_run(store, dive_row.id, run_id)
    setup, record = run_calibration(store, dive_row.id, run, calibration)
    if overrides:
        setup = overrides.apply(setup)
    selected, span_info = (span or Span()).select(store.call(queries.result_rows, run["id"], dive_row.id))
    if not selected:
        raise FitInputError(
            f"dive {dive_name}: no analysed frame in the span "
            f"(depth >= {span_info['depth_min_m']}, <= {span_info['depth_max_m']})"
        )
    rows = []
    for i, r in enumerate(selected):
        try:
            path = store.files.resolve(r["path"])
        except UnsafePath as exc:
            raise FitInputError(f"frame {r['frame_id']}: {exc}") from None
        rows.append(
            ManifestRow(
                index=i,
                file=str(path),
                camera=r["module"],
                wavelength_nm=int(r["wavelength_nm"]),
                exposure_s=float(r["exposure_s"]),
                gain_db=float(r["gain_db"]),
                depth_m=r["depth_m"],
            )
        )
    return DiveInputs(dive, run, setup, record, span_info, rows, store.files.root)


def fit_dive(
    inputs: DiveInputs,
    options: FitOptions | None = None,
    *,
    progress: Callable[[str, int, int], None] | None = None,
) -> DiveFit:
    """Analyse the span's frame files again (the fit needs their stacked pixels) and fit every wavelength."""
    options = options or FitOptions()
    workers = options.workers or os.cpu_count() or 1
    report = (lambda done, total: progress("analysing", done, total)) if progress else None
    try:
        an = analyze_rows(inputs.data_root, inputs.rows, inputs.setup, workers=workers, progress=report)
    except FrameSetError as exc:
        raise FitInputError(str(exc)) from None
    return DiveFit(inputs, fit_analysis(an, options, progress=progress))


def dive_fit_json(result: DiveFit) -> dict[str, Any]:
    """The fit document of a dive: `camcal.fitset.to_json` with the dive, run, span and calibration."""
    doc = to_json(result.fit)
    inp = result.inputs
    doc["inputs"].update(
        {
            "folder": str(inp.data_root),
            "dive": {"id": inp.dive["id"], "name": inp.dive["name"]},
            "run": {"id": inp.run["id"], "kind": inp.run["kind"], "label": inp.run["label"]},
            "span": inp.span,
            "calibration_record": None
            if inp.calibration is None
            else {k: inp.calibration[k] for k in ("id", "name", "version", "source")},
        }
    )
    doc["software"] = {"name": "camcal", "version": __version__}
    return doc


def store_dive_fit(store: Store, result: DiveFit, doc: dict[str, Any] | None = None) -> int:
    """Keep the fit in the store (table ``chisq_fits``); returns its id."""
    inp = result.inputs
    return store.add_chisq_fit(
        inp.dive["id"],
        doc if doc is not None else dive_fit_json(result),
        run_id=inp.run["id"],
        calibration_id=inp.calibration["id"] if inp.calibration else None,
        span=inp.span,
        label=f"run {inp.run['id']} ({inp.run['kind']})",
        software_version=__version__,
    )


__all__ = [
    "DiveFit",
    "DiveInputs",
    "DiveLookupError",
    "dive_fit_json",
    "dive_inputs",
    "fit_dive",
    "pick_run",
    "run_calibration",
    "store_dive_fit",
]
