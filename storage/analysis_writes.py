"""The store's writes of analysis: runs, frame results, λ_att points, attitude, linearity, χ² fits."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from sqlalchemy import delete, insert, literal, select, text, update
from sqlalchemy.orm import Session

from camcal.core.events import Event
from camcal.core.owner import this_process
from storage.base import StoreBase, now_unix_s
from storage.models import (
    AnalysisRun,
    AttenuationPoint,
    AttitudeSample,
    ChiSquareFitRecord,
    FrameResult,
    LinearityCheck,
)
from storage.queries.frames import frames_in
from storage.queries.runs import UNFINISHED, is_orphan


class AnalysisWrites(StoreBase):
    """What the analysis (live, re-analysis, ``camcal fit``) writes."""

    def analysis_run(
        self,
        dive_id: int,
        kind: str = "live",
        *,
        label: str = "",
        calibration: dict[str, Any] | None = None,
        calibration_id: int | None = None,
        software_version: str = "",
        create: bool = True,
    ) -> AnalysisRun | None:
        """The dive's live run (one per dive, shared by every ingest), or a new run of another kind."""
        values = {
            "dive_id": dive_id,
            "kind": kind,
            "label": label,
            "calibration": calibration or {},
            "calibration_id": calibration_id,
            "software_version": software_version,
            "created_unix_s": now_unix_s(),
            "status": "running",
            "n_frames": 0,
            "heartbeat_unix_s": None if kind == "live" else now_unix_s(),
            "owner": None if kind == "live" else this_process(),
        }
        with self.session() as s:
            if kind == "live":
                if create:  # the partial unique index turns a concurrent second insert into a no-op
                    s.execute(
                        self._insert(AnalysisRun.__table__)
                        .values(**values)
                        .on_conflict_do_nothing(index_elements=["dive_id"], index_where=text("kind = 'live'"))
                    )
                return s.scalars(
                    select(AnalysisRun).where(AnalysisRun.dive_id == dive_id, AnalysisRun.kind == "live")
                ).first()
            run = AnalysisRun(**values)
            s.add(run)
            s.flush()
            return run

    def finish_run(self, run_id: int, status: str = "done", n_frames: int | None = None) -> None:
        with self.session() as s:
            values: dict[str, Any] = {"status": status}
            if n_frames is not None:
                values["n_frames"] = n_frames
            s.execute(update(AnalysisRun).where(AnalysisRun.id == run_id).values(**values))

    def beat_runs(self, run_ids: Sequence[int]) -> None:
        """Say that runs ``run_ids`` are still queued or running (`storage.queries.runs.RUN_STALE_S`)."""
        if not run_ids:
            return
        with self.session() as s:
            s.execute(
                update(AnalysisRun)
                .where(AnalysisRun.id.in_(list(run_ids)), AnalysisRun.status.in_(UNFINISHED))
                .values(heartbeat_unix_s=now_unix_s(), owner=this_process())
            )

    def interrupt_stale_runs(self) -> list[dict[str, Any]]:
        """Mark ``interrupted`` the re-analyses queued or running whose process is gone.

        Gone: it stopped beating (`storage.queries.runs.RUN_STALE_S`), or it ran on this host and
        has ended (`camcal.core.owner.gone`: a server restarted at once after a kill). Returns them
        (id, dive, label) for the caller to say so. A run another live process still beats is left
        alone: a server starting beside a ``camcal reanalyze`` under way does not end it."""
        with self.session() as s:
            runs = s.scalars(
                select(AnalysisRun).where(AnalysisRun.kind != "live", AnalysisRun.status.in_(UNFINISHED))
            ).all()
            now = now_unix_s()
            ended = [{"id": r.id, "dive_id": r.dive_id, "label": r.label} for r in runs if is_orphan(r, now)]
            if ended:
                s.execute(
                    update(AnalysisRun)
                    .where(AnalysisRun.id.in_([r["id"] for r in ended]), AnalysisRun.status.in_(UNFINISHED))
                    .values(status="interrupted")
                )
            return ended

    def save_results(self, run_id: int, results: Sequence[dict[str, Any]]) -> int:
        """Store frame results (dicts of `FrameResult` columns with ``frame_id``); duplicates skipped."""
        if not results:
            return 0
        with self.session() as s:
            return self._insert_results(s, run_id, results)

    def _insert_results(self, s: Session, run_id: int, results: Sequence[dict[str, Any]]) -> int:
        # executemany of one cached statement per set of columns (a multi-row VALUES is compiled
        # anew each time, ~3 ms of CPU); a result without some column leaves it out, as before.
        table = FrameResult.__table__
        groups: dict[frozenset[str], list[dict[str, Any]]] = {}
        for r in results:
            row = {**r, "run_id": run_id}
            groups.setdefault(frozenset(row), []).append(row)
        stmt = (
            self._insert(table)
            .on_conflict_do_nothing(index_elements=["frame_id", "run_id"])
            .returning(FrameResult.id)
        )
        n = 0
        for keys, rows in groups.items():
            unknown = keys - set(table.columns.keys())
            if unknown:
                raise ValueError(f"frame results have no column(s) {sorted(unknown)}")
            n += len(s.execute(stmt, rows).all())  # rowcount is -1 for this statement on psycopg
        return n

    def commit_results(
        self,
        run_id: int,
        results: Sequence[dict[str, Any]],
        events: Sequence[Event] = (),
        *,
        upserts: Sequence[dict[str, Any]] = (),
        deletes: Sequence[str] = (),
        point_events: Callable[[dict[str, int]], list[Event]] | None = None,
    ) -> list[Event]:
        """Frame results, the λ_att visits they changed and the events of both, in one transaction
        (one commit, one fsync: a crash keeps all of them or none). ``point_events`` makes the
        visits' events from their point ids. Returns the events stored (``id`` set)."""
        stored = list(events)
        with self.session() as s:
            if results:
                self._insert_results(s, run_id, results)
            if upserts or deletes:
                ids = self._upsert_visit_points(s, run_id, upserts, deletes)
                if point_events is not None:
                    stored += point_events(ids)
            if stored:
                self._insert_events(s, stored)
        return stored

    def copy_results(
        self, src_run_id: int, dst_run_id: int, t_from: float | None = None, t_to: float | None = None
    ) -> int:
        """Copy the frame results of one run into another (a re-analysis that keeps I_center),
        of frames captured in [t_from, t_to] if given."""
        cols = [c.name for c in FrameResult.__table__.columns if c.name not in ("id", "run_id")]
        with self.session() as s:
            src = select(*[FrameResult.__table__.c[c] for c in cols], literal(dst_run_id)).where(
                FrameResult.run_id == src_run_id
            )
            if t_from is not None or t_to is not None:
                src = src.where(FrameResult.frame_id.in_(frames_in(None, t_from, t_to)))
            stmt = insert(FrameResult).from_select([*cols, "run_id"], src).returning(FrameResult.id)
            return len(s.execute(stmt).all())

    def add_attenuation_points(self, points: Sequence[dict[str, Any]]) -> list[int]:
        if not points:
            return []
        with self.session() as s:
            objs = [AttenuationPoint(**p) for p in points]
            s.add_all(objs)
            s.flush()
            return [o.id for o in objs]

    def save_visit_points(
        self, run_id: int, upserts: Sequence[dict[str, Any]], deletes: Sequence[str] = ()
    ) -> dict[str, int]:
        """Insert or update λ_att points by (run, ``visit_key``) and delete visits that are gone,
        in one transaction. Returns the point id of every upserted visit key."""
        if not upserts and not deletes:
            return {}
        with self.session() as s:
            return self._upsert_visit_points(s, run_id, upserts, deletes)

    def _upsert_visit_points(
        self, s: Session, run_id: int, upserts: Sequence[dict[str, Any]], deletes: Sequence[str]
    ) -> dict[str, int]:
        table = AttenuationPoint.__table__
        if deletes:
            s.execute(
                delete(AttenuationPoint).where(
                    AttenuationPoint.run_id == run_id, AttenuationPoint.visit_key.in_(list(deletes))
                )
            )
        self._upsert_many(s, table, upserts, ("run_id", "visit_key"))
        keys = [r["visit_key"] for r in upserts]
        ids = s.execute(
            select(AttenuationPoint.visit_key, AttenuationPoint.id).where(
                AttenuationPoint.run_id == run_id, AttenuationPoint.visit_key.in_(keys)
            )
        ).all()
        return {str(k): int(i) for k, i in ids}

    def add_attitude(self, samples: Sequence[dict[str, Any]]) -> None:
        if samples:
            with self.session() as s:
                s.execute(insert(AttitudeSample), list(samples))

    def upsert_linearity(self, rows: dict[str, Any] | Sequence[dict[str, Any]]) -> None:
        """Insert or replace linearity fits of (run, module, wavelength, sweep): one row, or
        several in one transaction (one commit: the ingest updates every fit of a tick at once)."""
        rows = [rows] if isinstance(rows, dict) else list(rows)
        if not rows:
            return
        keys = ("run_id", "module_id", "wavelength_nm", "sweep")
        with self.session() as s:
            self._upsert_many(s, LinearityCheck.__table__, rows, keys)

    def add_chisq_fit(
        self,
        dive_id: int,
        result: dict[str, Any],
        *,
        run_id: int | None = None,
        calibration_id: int | None = None,
        span: dict[str, Any] | None = None,
        label: str = "",
        software_version: str = "",
    ) -> int:
        """Keep a χ² fit of a dive (its JSON document); earlier fits stay. Returns its id."""
        with self.session() as s:
            rec = ChiSquareFitRecord(
                dive_id=dive_id,
                run_id=run_id,
                calibration_id=calibration_id,
                created_unix_s=now_unix_s(),
                software_version=software_version,
                label=label,
                span=span or {},
                result=result,
            )
            s.add(rec)
            s.flush()
            return rec.id
