"""Dives: list, details, timeline, λ_att table, runs, re-analysis, export."""

from __future__ import annotations

import errno
import os
import tempfile
import threading
import zipfile
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Query, Request
from fastapi.responses import FileResponse
from sqlalchemy.orm import Session
from starlette.background import BackgroundTask

from camcal.core.frameset import Setup, parse_setup
from ingest.dive_export import export_dive_with_results
from ingest.reanalysis import (
    ReanalysisInputError,
    ReanalysisOptions,
    UnknownCalibration,
    reanalyse,
    start_reanalysis,
)
from ingest.spans import Span, attenuation_over_span, table_rows
from server.deps import FloatQuery, IdPath, IdQuery, OperatorDep, SettingsDep, StoreDep
from server.errors import Invalid, NotFound, Unavailable
from server.openapi import BUSY, NOT_FOUND
from server.schemas import (
    AttenuationTable,
    ChisqFitPublic,
    ChisqFitSummary,
    DivePublic,
    DiveSettings,
    ReanalysisCreate,
    RunPublic,
    Timeline,
)
from storage import queries
from storage.models import Dive
from storage.store import Store

router = APIRouter(tags=["dives"])


def dive_or_404(store: Store, dive_id: IdPath) -> Dive:
    dive = store.call(Session.get, Dive, dive_id)
    if dive is None:
        raise NotFound(f"no dive {dive_id}")
    return dive


@router.get("/api/dives", response_model=list[DivePublic])
def list_dives(store: StoreDep, settings: SettingsDep) -> list[dict[str, Any]]:
    """Every dive, newest first, with its frame count, time range and deepest depth, and whether it
    is open or has ended and why."""
    return store.call(queries.dives, None, settings.dive_rules)


@router.get("/api/dives/{dive_id}", response_model=DivePublic)
def get_dive(dive_id: IdPath, store: StoreDep, settings: SettingsDep) -> dict[str, Any]:
    """One dive as the list has it: open or ended, and why."""
    rows = store.call(queries.dives, dive_id, settings.dive_rules)
    if not rows:
        raise NotFound(f"no dive {dive_id}")
    return rows[0]


@router.get("/api/dives/{dive_id}/timeline", response_model=Timeline)
def timeline(
    dive_id: IdPath, store: StoreDep, max_points: Annotated[int, Query(ge=10, le=5000)] = 600
) -> dict[str, Any]:
    """Depth over the dive, the frames on it (thinned to ~2000 marks) and the alarms."""
    dive_or_404(store, dive_id)
    return store.call(queries.timeline, dive_id, max_points)


@router.get("/api/dives/{dive_id}/settings", response_model=DiveSettings)
def settings_of_dive(dive_id: IdPath, store: StoreDep) -> dict[str, Any]:
    """The modules, wavelengths, exposures and gains the dive's frames were taken with."""
    dive_or_404(store, dive_id)
    return store.call(queries.frame_settings, dive_id)


@router.get("/api/dives/{dive_id}/runs", response_model=list[RunPublic])
def runs(dive_id: IdPath, store: StoreDep) -> list[dict[str, Any]]:
    """The dive's analysis runs: the live one and every re-analysis."""
    dive_or_404(store, dive_id)
    return store.call(queries.runs, dive_id)


def run_setup(store: Store, dive_id: IdPath, run_id: int | None) -> tuple[int, Setup]:
    """The run asked for (default: the live run, else the newest) and the setup it was analysed with."""
    try:
        run = store.call(queries.chosen_run, dive_id, run_id)
    except queries.RunLookupError as exc:
        raise NotFound(str(exc)) from None
    return run["id"], store.call(queries.setup_in_force, dive_id, run)


@router.get("/api/dives/{dive_id}/attenuation", response_model=AttenuationTable)
def attenuation_table(
    dive_id: IdPath,
    store: StoreDep,
    run: IdQuery = None,
    depth_min_m: FloatQuery = None,
    depth_max_m: FloatQuery = None,
    t_from: FloatQuery = None,
    t_to: FloatQuery = None,
) -> dict[str, Any]:
    """λ_att per wavelength with statistical and systematic errors, over a span of the dive.

    Default span: the station (frames within 50 m of the deepest frame).
    Each row lists the near/far setting pairs it combines, with their LEM depth. A span that
    crosses depths (the whole dive: 1200, 2021, 3420 m) is stacked and paired per depth band:
    ``bands`` holds a table per band, and a row has no value (its note names each band's) when
    the bands' water differs.
    """
    dive_or_404(store, dive_id)
    run_id, setup = run_setup(store, dive_id, run)

    rows = store.call(queries.result_rows, run_id, dive_id)
    span, table = attenuation_over_span(rows, setup, Span(depth_min_m, depth_max_m, t_from, t_to))
    return {
        "run_id": run_id,
        "span": span,
        "calibration": setup.to_json(),
        **table_rows(table),
    }


@router.get("/api/dives/{dive_id}/fits", response_model=list[ChisqFitSummary])
def chisq_fits(dive_id: IdPath, store: StoreDep) -> list[dict[str, Any]]:
    """The χ² fits (λ_abs, λ_sca) kept for the dive by ``camcal fit --dive``, oldest first (no documents)."""
    dive_or_404(store, dive_id)
    return store.call(queries.chisq_fits, dive_id)


@router.get("/api/dives/{dive_id}/fits/latest", response_model=ChisqFitPublic)
def latest_chisq_fit(dive_id: IdPath, store: StoreDep, run: IdQuery = None) -> dict[str, Any]:
    """The newest χ² fit of the dive (of one run's inputs if ``run`` is given), with its document:
    λ_abs, λ_sca per wavelength with errors, the I_center check, the Δχ² map and the fitted profiles."""
    dive = dive_or_404(store, dive_id)
    fit = store.call(queries.latest_chisq_fit, dive_id, run)
    if fit is None:
        raise NotFound(f"no χ² fit kept for dive {dive_id}: run `camcal fit --dive {dive.name}`")
    return fit


@router.post(
    "/api/dives/{dive_id}/reanalyses",
    status_code=202,
    response_model=RunPublic,
    responses={**NOT_FOUND, **BUSY},
)
def create_reanalysis(
    dive_id: IdPath,
    body: ReanalysisCreate,
    request: Request,
    store: StoreDep,
    settings: SettingsDep,
    who: OperatorDep,
) -> dict[str, Any]:
    """Re-analyse the dive with other distances, I0'/I0 or linear range, beside the original results.

    Returns the new run at once (status ``queued``, then ``running``): re-analyses run one at a
    time, in the order asked for, and a few may wait (503 beyond). Poll ``GET
    /api/dives/{id}/runs`` for its end.
    """
    dive_or_404(store, dive_id)
    run_setup(store, dive_id, None)  # 404 for a dive that was never analysed

    def adjust(base: Setup) -> Setup:
        data = base.model_dump()
        for cam, d in (body.cameras or {}).items():  # the camera's other values (focal_px...) are kept
            data["cameras"].setdefault(cam, {}).update(d.model_dump(exclude_none=True))
        for wl, r in (body.emission_ratio or {}).items():
            data["emission_ratio"][wl] = r.model_dump()
        if body.linear_range:
            data["linear_range"] = body.linear_range
        return parse_setup(data, "re-analysis")

    try:
        started = start_reanalysis(
            store,
            dive_id,
            actor=who,
            default_label=f"re-analysis by {who}",
            label=body.label,
            calibration=body.calibration_id,
            adjust=adjust,
        )
    except UnknownCalibration:
        raise NotFound(f"no calibration {body.calibration_id}") from None
    except ReanalysisInputError as exc:
        raise Invalid(str(exc)) from None
    run_id, setup = started.run_id, started.setup

    def job(cancel: threading.Event) -> None:
        options = ReanalysisOptions(workers=settings.reanalysis_workers)
        reanalyse(store, dive_id, run_id, setup, options, cancel=cancel)

    request.app.state.reanalyses.submit(run_id, job)
    return next(r for r in store.call(queries.runs, dive_id) if r["id"] == run_id)


@router.get(
    "/api/dives/{dive_id}/export",
    response_class=FileResponse,
    responses={200: {"content": {"application/zip": {}}}, **NOT_FOUND, **BUSY},
)
def export(
    dive_id: IdPath,
    request: Request,
    store: StoreDep,
    fmt: Annotated[str, Query(alias="format", pattern="^(csv|parquet)$")] = "csv",
    run: IdQuery = None,
) -> FileResponse:
    """The dive's tables as a ZIP of CSV or Parquet files, streamed from a temporary file.

    Exports run a few at a time (``exports_at_once``, default 1): another is refused with 503
    and ``Retry-After`` while they do.
    """
    dive = dive_or_404(store, dive_id)
    run_id, _ = run_setup(store, dive_id, run)
    slots = request.app.state.exports
    slots.take()

    try:
        path = _export_zip(store, dive_id, fmt, run_id)
    except OSError as exc:
        if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        raise Unavailable(
            f"no room for the export in {tempfile.gettempdir()} ({exc.strerror}): free space on the "
            "ship computer and try again"
        ) from None
    finally:
        slots.give()
    return FileResponse(
        path,
        media_type="application/zip",
        filename=f"{dive.name}-{fmt}.zip",
        background=BackgroundTask(os.unlink, path),
    )


def _export_zip(store: Store, dive_id: int, fmt: str, run_id: int) -> str:
    """The dive's tables written into a temporary ZIP file (removed again if that fails)."""
    fd, name = tempfile.mkstemp(prefix="camcal-export-", suffix=".zip")
    os.close(fd)
    try:
        with tempfile.TemporaryDirectory() as tmp, zipfile.ZipFile(name, "w", zipfile.ZIP_DEFLATED) as zf:
            for f in export_dive_with_results(store, dive_id, Path(tmp), (fmt,), run_id):
                zf.write(f, f.name)
    except BaseException:
        os.unlink(name)
        raise
    return name
