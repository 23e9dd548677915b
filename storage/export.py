"""Export a dive's tables to CSV and Parquet (one file per table)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.csv as pa_csv
import pyarrow.parquet as pq
from sqlalchemy import select, true

from camcal.core.files import write_whole
from camcal.core.utctime import iso_utc
from storage import queries
from storage.audit import describe
from storage.base import now_unix_s
from storage.models import (
    Alarm,
    AttenuationPoint,
    AttitudeSample,
    AuditEntry,
    Dive,
    Frame,
    FrameResult,
    LinearityCheck,
    SensorSample,
)
from storage.store import Store

FORMATS = ("csv", "parquet")
_SKIP = {"profile", "fit", "points", "details", "payload"}


def _columns(model: Any) -> list[Any]:
    return [c for c in model.__table__.columns if c.name not in _SKIP]


def dive_tables(store: Store, dive_id: int, run_id: int | None = None) -> dict[str, pa.Table]:
    """The dive's tables as Arrow tables: frames (with their results in ``run_id``), sensors,
    attitude, the λ_att series (of ``run_id``: a re-analysis's points are not mixed with the live
    run's), linearity, and the alarms and audit entries of the dive's time (the ship's clock, from
    the dive's start to its end or now; they carry no dive of their own)."""
    out: dict[str, pa.Table] = {}
    with store.read() as s:
        dive = s.get(Dive, dive_id)
        t0 = dive.started_unix_s if dive is not None else 0.0
        t1 = dive.ended_unix_s if dive is not None and dive.ended_unix_s is not None else now_unix_s()
        fcols = _columns(Frame)
        rcols = [c for c in _columns(FrameResult) if c.name not in ("id", "frame_id")]
        q = select(*fcols, *rcols).select_from(Frame)
        if run_id is not None:
            q = q.outerjoin(FrameResult, (FrameResult.frame_id == Frame.id) & (FrameResult.run_id == run_id))
        else:
            q = select(*fcols).select_from(Frame)
            rcols = []
        names = [c.name for c in fcols] + [c.name for c in rcols]
        # in the order they were taken, on the ship's clock (`captured_ship_unix_s`: the dive's one axis)
        taken = queries.ship_time(Frame)
        rows = s.execute(q.where(Frame.dive_id == dive_id).order_by(taken, Frame.id)).all()
        out["frames"] = _table(names, rows)
        tables: tuple[tuple[str, Any, Any], ...] = (
            ("sensor_samples", SensorSample, SensorSample.dive_id == dive_id),
            ("attitude", AttitudeSample, AttitudeSample.dive_id == dive_id),
            (
                "attenuation",
                AttenuationPoint,
                (AttenuationPoint.dive_id == dive_id)
                & (AttenuationPoint.run_id == run_id if run_id is not None else true()),
            ),
        )
        for name, model, where in tables:
            cols = _columns(model)
            rows = s.execute(select(*cols).where(where).order_by(model.id)).all()
            out[name] = _table([c.name for c in cols], rows)
        if run_id is not None:
            cols = _columns(LinearityCheck)
            rows = s.execute(select(*cols).where(LinearityCheck.run_id == run_id)).all()
            out["linearity"] = _table([c.name for c in cols], rows)
        cols = _columns(Alarm)
        when = Alarm.raised_unix_s.between(t0, t1)
        out["alarms"] = _table(
            [c.name for c in cols], s.execute(select(*cols).where(when).order_by(Alarm.id)).all()
        )
        out["audit_log"] = _audit_table(
            s.scalars(select(AuditEntry).where(AuditEntry.t_unix_s.between(t0, t1)).order_by(AuditEntry.id))
        )
    return out


def _audit_table(entries: Any) -> pa.Table:
    """The audit log as the review page shows it: each entry with what happened in words (``what``)
    and its whole record (``details``, JSON)."""
    names = ["id", "t_unix_s", "actor", "action", "target"]
    rows = []
    for a in entries:
        entry = {n: getattr(a, n) for n in names} | {"details": a.details}
        rows.append(
            (*(entry[n] for n in names), describe(entry), json.dumps(a.details or {}, ensure_ascii=False))
        )
    return _table([*names, "what", "details"], rows)


def _table(names: list[str], rows: Sequence[Any]) -> pa.Table:
    columns: list[Sequence[Any]] = list(zip(*rows, strict=True)) if rows else [[] for _ in names]
    return with_utc_times(pa.table({n: pa.array(list(col)) for n, col in zip(names, columns, strict=True)}))


def with_utc_times(table: pa.Table) -> pa.Table:
    """``table`` with ``X_utc`` beside each ``X_unix_s`` column: the same time as ISO 8601 UTC text to
    the millisecond (``2026-11-28T01:14:05.123Z``), for people and spreadsheets; the UNIX seconds
    stay the exact value."""
    for name in [n for n in table.column_names if n.endswith("_unix_s")]:
        seconds = table.column(name)
        if not (pa.types.is_floating(seconds.type) or pa.types.is_integer(seconds.type)):
            continue  # an empty column of an empty table has no type to convert
        text = pa.array([iso_utc(v) for v in seconds.to_pylist()], pa.string())
        table = table.add_column(
            table.column_names.index(name) + 1, name.removesuffix("_unix_s") + "_utc", text
        )
    return table


def export_dive(
    store: Store,
    dive_id: int,
    out: Path,
    formats: tuple[str, ...] = FORMATS,
    run_id: int | None = None,
    extra: dict[str, list[dict[str, Any]]] | None = None,
) -> list[Path]:
    """Write each table as ``<out>/<table>.csv`` and/or ``.parquet``; returns the files.

    ``extra``: more tables as rows of plain values (``ingest.dive_export`` adds ``lambda_att``).

    With a run, also ``setup.json`` (what its numbers were computed with: distances, I0'/I0, the
    linear range, the series' settings, in the frame-set format) and ``run.json`` (which dive and
    run the tables hold, the calibration record, the software, when exported).
    """
    unknown = set(formats) - set(FORMATS)
    if unknown:
        raise ValueError(f"unknown export format(s) {sorted(unknown)}; choose from {', '.join(FORMATS)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = [] if run_id is None else _write_run(store, dive_id, run_id, out)
    tables = dive_tables(store, dive_id, run_id)
    for name, rows in (extra or {}).items():
        tables[name] = with_utc_times(pa.Table.from_pylist(rows)) if rows else pa.table({})
    for name, table in tables.items():
        # Each table whole or not at all: a full disk leaves no half-written file, and an older
        # export's file is replaced only by a whole one.
        if "csv" in formats:
            write_whole(out / f"{name}.csv", partial(pa_csv.write_csv, table))
            written.append(out / f"{name}.csv")
        if "parquet" in formats:
            write_whole(out / f"{name}.parquet", partial(pq.write_table, table))
            written.append(out / f"{name}.parquet")
    return written


def _write_run(store: Store, dive_id: int, run_id: int, out: Path) -> list[Path]:
    """``setup.json`` and ``run.json`` of the exported run (each whole or not at all)."""
    with store.read() as s:
        dive = queries.dive_record(s, dive_id) or {}
        run = queries.chosen_run(s, dive_id, run_id)
        setup = queries.setup_in_force(s, dive_id, run)
    keys = ("id", "kind", "label", "calibration_id", "software_version", "created_unix_s")
    run_about = {k: run[k] for k in keys} | {"created_utc": iso_utc(run["created_unix_s"])}
    exported = now_unix_s()
    about = {
        "dive": {"id": dive_id, "name": dive.get("name")},
        "run": run_about,
        "setup_from": {
            "run": "the run's calibration",
            "dive": "the dive's own setup (imported)",
            "defaults": "the defaults (T-REX)",
        }[run["setup_from"]],
        "exported_unix_s": exported,
        "exported_utc": iso_utc(exported),
    }
    files = []
    for name, doc in (("setup.json", setup.to_json()), ("run.json", about)):
        text = json.dumps(doc, indent=2, ensure_ascii=False) + "\n"
        write_whole(out / name, partial(_write_text, text))
        files.append(out / name)
    return files


def _write_text(text: str, path: Path) -> None:
    path.write_text(text, encoding="utf-8")
