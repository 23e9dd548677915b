"""The store: every database access of camcal goes through here.

One writer (the ingest's store thread, or an import) and any number of
readers (the server). Batches are written in one transaction each.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, delete, func, insert, literal, select, text, tuple_, update
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session, sessionmaker

from storage.db import DataPaths, make_engine, migrate
from storage.files import FrameFiles
from storage.jsonsafe import finite_json
from storage.models import (
    Alarm,
    AnalysisRun,
    AttenuationPoint,
    AttitudeSample,
    AuditEntry,
    Calibration,
    ChiSquareFitRecord,
    CommandRecord,
    Dive,
    Event,
    Frame,
    FrameResult,
    Gap,
    IngestCounter,
    LinearityCheck,
    Module,
    SensorBatch,
    SensorSample,
)


def now_unix_s() -> float:
    return time.time()


#: Key of the advisory lock that serialises choosing (or creating) the open dive.
DIVE_LOCK_KEY = 0x63616D64697665  # "camdive"

#: Order of a command's states: a late, older status never moves it back.
COMMAND_STATES = {"pending": 0, "sent": 1, "accepted": 2, "in_progress": 3, "done": 4, "rejected": 4}


def calibration_dict(c: Calibration) -> dict[str, Any]:
    return {
        "id": c.id,
        "name": c.name,
        "version": c.version,
        "source": c.source,
        "valid_from_unix_s": c.valid_from_unix_s,
        "valid_to_unix_s": c.valid_to_unix_s,
        "values": c.values,
        "created_unix_s": c.created_unix_s,
    }


def command_dict(c: CommandRecord) -> dict[str, Any]:
    return {
        "id": c.id,
        "module": c.module_id,
        "action": c.action,
        "target_version": c.target_version,
        "payload": c.payload,
        "apply": c.apply,
        "issued_by": c.issued_by,
        "issued_unix_s": c.issued_unix_s,
        "state": c.state,
        "reason": c.reason,
        "attempts": c.attempts,
        "updated_unix_s": c.updated_unix_s,
    }


@dataclass
class FrameRow:
    """A frame to store: the ``frames`` columns (``dive_id`` is set by the store)."""

    module_id: str
    boot: str
    seq: int
    captured_unix_s: float
    received_unix_s: float
    wavelength_nm: int
    exposure_s: float
    gain_db: float
    depth_m: float | None
    width_px: int
    height_px: int
    path: str
    size_bytes: int
    sha256: str
    schedule_version: int = 0
    source: str = "live"
    dive_id: int | None = None

    def as_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


@dataclass
class SensorBatchRow:
    """A ``sensors`` message: its identity and its samples (dicts of column -> value)."""

    module_id: str
    boot: str
    seq: int
    received_unix_s: float
    samples: list[dict[str, Any]] = field(default_factory=list)
    sha256: str | None = None


@dataclass
class BatchOutcome:
    """What a batch commit did: ids of new frames by (module, boot, seq); duplicates skipped."""

    new_frames: dict[tuple[str, str, int], int]
    duplicate_frames: list[tuple[str, str, int]]
    new_sensor_batches: list[tuple[str, str, int]]
    duplicate_sensor_batches: list[tuple[str, str, int]]
    events: list[dict[str, Any]] = field(default_factory=list)  # stored with the frames, ``id`` set


class Store:
    """The database (any SQLAlchemy URL; SQLite by default) and the frame files."""

    def __init__(self, engine: Engine, files: FrameFiles) -> None:
        self.engine = engine
        self.files = files
        self._sessions = sessionmaker(engine, expire_on_commit=False)

    @classmethod
    def open(
        cls,
        data_dir: Path,
        url: str | None = None,
        *,
        run_migrations: bool = True,
        sqlite_synchronous: str = "FULL",
    ) -> Store:
        """Open (and by default migrate) the store of a data folder."""
        paths = DataPaths(Path(data_dir))
        paths.root.mkdir(parents=True, exist_ok=True)
        engine = make_engine(url or paths.sqlite_url(), sqlite_synchronous=sqlite_synchronous)
        if run_migrations:
            migrate(engine)
        return cls(engine, FrameFiles(paths.root))

    def close(self) -> None:
        self.engine.dispose()

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session in a transaction: committed on success, rolled back on error."""
        with self._sessions() as s, s.begin():
            yield s

    def read(self) -> Session:
        """A session for reading (the caller closes it)."""
        return self._sessions()

    # ------------------------------------------------------------ helpers
    def _insert(self, table: Any) -> Any:
        name = self.engine.dialect.name
        if name == "sqlite":
            return sqlite.insert(table)
        if name == "postgresql":
            return postgresql.insert(table)
        raise NotImplementedError(f"conflict-free inserts are written for SQLite and PostgreSQL, not {name}")

    # ------------------------------------------------------------ dives
    def _serialise(self, s: Session, key: int) -> None:
        """Hold a lock until ``s`` commits, so get-or-create steps of several processes queue.

        PostgreSQL: a transaction-level advisory lock on ``key``. SQLite: a
        write statement that changes nothing takes the database's write lock.
        """
        if self.engine.dialect.name == "postgresql":
            s.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": key})
        else:
            s.execute(update(Dive).where(literal(False)).values(name=Dive.name))

    def open_dive(self, name: str, setup: dict[str, Any] | None = None) -> Dive:
        """The dive called ``name``, created if there is none (safe when several processes ask at once)."""
        with self.session() as s:
            s.execute(
                self._insert(Dive.__table__)
                .values(name=name, started_unix_s=now_unix_s(), notes="", setup=setup or {})
                .on_conflict_do_nothing(index_elements=["name"])
            )
            return s.scalars(select(Dive).where(Dive.name == name)).one()

    def current_dive(
        self, *, create: bool = True, name: str | None = None, setup: dict[str, Any] | None = None
    ) -> Dive | None:
        """The dive called ``name`` if one is given, else the open dive (not ended), the most recent first.

        Created if missing and ``create``. Safe under concurrency: processes
        asking at once for a named dive all get the same row (the name is
        unique), and the choice of the open dive is serialised by a lock.
        """
        if name is not None:
            return self.open_dive(name, setup) if create else self.dive_by_name(name)
        with self.session() as s:
            if create:
                self._serialise(s, DIVE_LOCK_KEY)
            dive = s.scalars(
                select(Dive).where(Dive.ended_unix_s.is_(None)).order_by(Dive.id.desc()).limit(1)
            ).first()
            if dive is None and create:
                t = now_unix_s()
                dive = Dive(
                    name=time.strftime("dive-%Y%m%d-%H%M%S", time.gmtime(t)),
                    started_unix_s=t,
                    notes="",
                    setup=setup or {},
                )
                s.add(dive)
                s.flush()
            return dive

    def create_dive(
        self, name: str, setup: dict[str, Any] | None = None, started_unix_s: float | None = None
    ) -> Dive:
        with self.session() as s:
            dive = Dive(name=name, started_unix_s=started_unix_s or now_unix_s(), notes="", setup=setup or {})
            s.add(dive)
            s.flush()
            return dive

    def dive_by_name(self, name: str) -> Dive | None:
        with self.read() as s:
            return s.scalars(select(Dive).where(Dive.name == name)).first()

    def end_dive(self, dive_id: int, t: float | None = None) -> None:
        with self.session() as s:
            s.execute(update(Dive).where(Dive.id == dive_id).values(ended_unix_s=t or now_unix_s()))

    # ------------------------------------------------------------ modules
    def touch_module(self, module_id: str, *, seen_unix_s: float | None = None, **values: Any) -> None:
        """Create or update a module row (last seen, boot, schedule, distance...)."""
        t = seen_unix_s or now_unix_s()
        with self.session() as s:
            self._ensure_modules(s, [module_id], t)
            mod = s.get_one(Module, module_id)
            mod.last_seen_unix_s = max(mod.last_seen_unix_s, t)
            for k, v in values.items():
                if v is not None:
                    setattr(mod, k, v)

    def _ensure_modules(self, s: Session, module_ids: Iterable[str], t: float) -> None:
        """Module rows for ``module_ids`` (one statement; a row another process just added is kept)."""
        ids = sorted(set(module_ids))
        if ids:
            s.execute(
                self._insert(Module.__table__)
                .values([{"id": m, "first_seen_unix_s": t, "last_seen_unix_s": t} for m in ids])
                .on_conflict_do_nothing(index_elements=["id"])
            )

    # ------------------------------------------------------------ ingest
    def commit_batch(
        self,
        dive_id: int,
        frames: Sequence[FrameRow],
        sensors: Sequence[SensorBatchRow] = (),
        frame_event: Callable[[FrameRow, int], dict[str, Any]] | None = None,
    ) -> BatchOutcome:
        """Insert frames and sensor batches in one transaction, skipping any already stored.

        (module, boot, seq) is unique for frames and for sensor batches, so a
        resend after a lost acknowledgement changes nothing. ``frame_event``
        makes the event of each new frame (given the row and its id); the
        events are written in the same transaction, so a crash can never
        leave a stored frame without its event.
        """
        t = now_unix_s()
        new_frames: dict[tuple[str, str, int], int] = {}
        new_sensors: list[tuple[str, str, int]] = []
        with self.session() as s:
            self._ensure_modules(s, [f.module_id for f in frames] + [b.module_id for b in sensors], t)
            if frames:
                rows = []
                for f in frames:
                    d = f.as_dict()
                    d["dive_id"] = f.dive_id or dive_id
                    rows.append(d)
                stmt = (
                    self._insert(Frame.__table__)
                    .values(rows)
                    .on_conflict_do_nothing(index_elements=["module_id", "boot", "seq"])
                    .returning(Frame.id, Frame.module_id, Frame.boot, Frame.seq)
                )
                for fid, mid, boot, seq in s.execute(stmt):
                    new_frames[(mid, boot, int(seq))] = int(fid)
            for b in sensors:
                stmt = (
                    self._insert(SensorBatch.__table__)
                    .values(
                        module_id=b.module_id,
                        boot=b.boot,
                        seq=b.seq,
                        count=len(b.samples),
                        received_unix_s=b.received_unix_s,
                        sha256=b.sha256,
                    )
                    .on_conflict_do_nothing(index_elements=["module_id", "boot", "seq"])
                    .returning(SensorBatch.id)
                )
                if s.execute(stmt).first() is None:
                    continue
                new_sensors.append((b.module_id, b.boot, b.seq))
                if b.samples:
                    s.execute(
                        insert(SensorSample),
                        [{**smp, "module_id": b.module_id, "dive_id": dive_id} for smp in b.samples],
                    )
            events: list[dict[str, Any]] = []
            if frame_event is not None and new_frames:
                for f in frames:
                    fid = new_frames.get((f.module_id, f.boot, f.seq))
                    if fid is not None:
                        events.append(frame_event(f, fid))
                self._insert_events(s, events)
        keys = [(f.module_id, f.boot, f.seq) for f in frames]
        skeys = [(b.module_id, b.boot, b.seq) for b in sensors]
        return BatchOutcome(
            new_frames=new_frames,
            duplicate_frames=[k for k in keys if k not in new_frames],
            new_sensor_batches=new_sensors,
            duplicate_sensor_batches=[k for k in skeys if k not in new_sensors],
            events=events,
        )

    def stored_checksums(
        self, frame_keys: Sequence[tuple[str, str, int]], sensor_keys: Sequence[tuple[str, str, int]]
    ) -> tuple[dict[tuple[str, str, int], str | None], dict[tuple[str, str, int], str | None]]:
        """The sha256 of frames and sensor batches already stored under these keys (module, boot, seq)."""
        frames: dict[tuple[str, str, int], str | None] = {}
        sensors: dict[tuple[str, str, int], str | None] = {}
        with self.read() as s:
            for table, keys, out in (
                (Frame, frame_keys, frames),
                (SensorBatch, sensor_keys, sensors),
            ):
                for chunk in _chunks(sorted(set(keys)), 300):
                    rows = s.execute(
                        select(table.module_id, table.boot, table.seq, table.sha256).where(
                            tuple_(table.module_id, table.boot, table.seq).in_(chunk)
                        )
                    )
                    for mid, boot, seq, sha in rows:
                        out[(mid, boot, int(seq))] = sha
        return frames, sensors

    def known_seqs(self, module_id: str, boot: str) -> set[int]:
        """Every sequence number of a module's boot that is stored (frames and sensor batches)."""
        with self.read() as s:
            a = s.scalars(select(Frame.seq).where(Frame.module_id == module_id, Frame.boot == boot))
            b = s.scalars(
                select(SensorBatch.seq).where(SensorBatch.module_id == module_id, SensorBatch.boot == boot)
            )
            return {int(x) for x in a} | {int(x) for x in b}

    def record_gap(self, module_id: str, boot: str, first_seq: int, last_seq: int) -> int:
        with self.session() as s:
            gap = Gap(
                module_id=module_id,
                boot=boot,
                first_seq=first_seq,
                last_seq=last_seq,
                detected_unix_s=now_unix_s(),
            )
            s.add(gap)
            s.flush()
            return gap.id

    def fill_gaps(self, module_id: str, boot: str, covers: Callable[[int, int], bool]) -> list[int]:
        """Mark open gaps filled once every number in them has arrived (``covers(first, last)``)."""
        filled = []
        with self.session() as s:
            gaps = s.scalars(
                select(Gap).where(Gap.module_id == module_id, Gap.boot == boot, Gap.filled_unix_s.is_(None))
            ).all()
            for g in gaps:
                if covers(g.first_seq, g.last_seq):
                    g.filled_unix_s = now_unix_s()
                    filled.append(g.id)
        return filled

    def open_gaps(self, module_id: str | None = None) -> list[Gap]:
        with self.read() as s:
            q = select(Gap).where(Gap.filled_unix_s.is_(None))
            if module_id:
                q = q.where(Gap.module_id == module_id)
            return list(s.scalars(q.order_by(Gap.id)))

    # ------------------------------------------------------------ analysis
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

    def save_results(self, run_id: int, results: Sequence[dict[str, Any]]) -> int:
        """Store frame results (dicts of `FrameResult` columns with ``frame_id``); duplicates skipped."""
        if not results:
            return 0
        rows = [{**r, "run_id": run_id} for r in results]
        with self.session() as s:
            stmt = (
                self._insert(FrameResult.__table__)
                .values(rows)
                .on_conflict_do_nothing(index_elements=["frame_id", "run_id"])
                .returning(FrameResult.id)
            )
            return len(s.execute(stmt).all())  # rowcount is -1 for this statement on psycopg

    def frames_without_result(
        self, dive_id: int, run_id: int, limit: int = 100_000, modules: Sequence[str] = ()
    ) -> list[Frame]:
        """Stored frames of a dive that the run has not analysed (e.g. after a crash), of ``modules``
        if given (an ingest recovers only the frames of the modules it serves)."""
        with self.read() as s:
            done = select(FrameResult.frame_id).where(FrameResult.run_id == run_id)
            q = select(Frame).where(Frame.dive_id == dive_id, Frame.id.not_in(done))
            if modules:
                q = q.where(Frame.module_id.in_(list(modules)))
            return list(s.scalars(q.order_by(Frame.id).limit(limit)))

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
                src = src.where(FrameResult.frame_id.in_(self._frames_in(None, t_from, t_to)))
            stmt = insert(FrameResult).from_select([*cols, "run_id"], src).returning(FrameResult.id)
            return len(s.execute(stmt).all())

    @staticmethod
    def _frames_in(dive_id: int | None, t_from: float | None, t_to: float | None) -> Any:
        q = select(Frame.id)
        if dive_id is not None:
            q = q.where(Frame.dive_id == dive_id)
        if t_from is not None:
            q = q.where(Frame.captured_unix_s >= t_from)
        if t_to is not None:
            q = q.where(Frame.captured_unix_s <= t_to)
        return q

    def result_rows(self, run_id: int, dive_id: int) -> list[dict[str, Any]]:
        """Frames of a dive joined with their result in a run, in capture order."""
        with self.read() as s:
            rows = s.execute(
                select(
                    Frame.id,
                    Frame.module_id,
                    Frame.wavelength_nm,
                    Frame.exposure_s,
                    Frame.gain_db,
                    Frame.captured_unix_s,
                    Frame.depth_m,
                    Frame.path,
                    FrameResult.status,
                    FrameResult.center_gray,
                    FrameResult.i_center_gray,
                    FrameResult.i_center_err_gray,
                )
                .join(FrameResult, (FrameResult.frame_id == Frame.id) & (FrameResult.run_id == run_id))
                .where(Frame.dive_id == dive_id)
                .order_by(Frame.captured_unix_s, Frame.id)
            ).all()
        keys = (
            "frame_id",
            "module",
            "wavelength_nm",
            "exposure_s",
            "gain_db",
            "captured_unix_s",
            "depth_m",
            "path",
            "status",
            "center_gray",
            "i_center_gray",
            "i_center_err_gray",
        )
        return [dict(zip(keys, r, strict=True)) for r in rows]

    def dive_frames(
        self, dive_id: int, t_from: float | None = None, t_to: float | None = None
    ) -> list[tuple[int, str]]:
        """(frame id, relative path) of every frame of a dive (captured in [t_from, t_to] if given)."""
        with self.read() as s:
            q = select(Frame.id, Frame.path).where(Frame.id.in_(self._frames_in(dive_id, t_from, t_to)))
            return [(int(i), p) for i, p in s.execute(q.order_by(Frame.id))]

    def frame_modules(self, frame_ids: Iterable[int]) -> dict[int, str]:
        """The module of each of the given frames."""
        ids = list(frame_ids)
        out: dict[int, str] = {}
        with self.read() as s:
            for i in range(0, len(ids), 500):
                q = select(Frame.id, Frame.module_id).where(Frame.id.in_(ids[i : i + 500]))
                out.update((int(f), m) for f, m in s.execute(q))
        return out

    def locate_frames(
        self, keys: Iterable[tuple[str, str, int]]
    ) -> dict[tuple[str, str, int], tuple[int, int]]:
        """(frame id, dive id) of stored frames by (module, boot, seq); keys not stored are left out."""
        keys = list(dict.fromkeys(keys))
        out: dict[tuple[str, str, int], tuple[int, int]] = {}
        with self.read() as s:
            for i in range(0, len(keys), 500):
                q = select(Frame.id, Frame.dive_id, Frame.module_id, Frame.boot, Frame.seq).where(
                    tuple_(Frame.module_id, Frame.boot, Frame.seq).in_(keys[i : i + 500])
                )
                for fid, did, m, b, seq in s.execute(q):
                    out[(m, b, int(seq))] = (int(fid), int(did))
        return out

    def dives_with_frames(self, t_from: float | None = None, t_to: float | None = None) -> list[Dive]:
        """The dives holding frames captured in [t_from, t_to], oldest first."""
        with self.read() as s:
            ids = select(Frame.dive_id).where(Frame.id.in_(self._frames_in(None, t_from, t_to))).distinct()
            return list(s.scalars(select(Dive).where(Dive.id.in_(ids)).order_by(Dive.id)))

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
        table = AttenuationPoint.__table__
        with self.session() as s:
            if deletes:
                s.execute(
                    delete(AttenuationPoint).where(
                        AttenuationPoint.run_id == run_id, AttenuationPoint.visit_key.in_(list(deletes))
                    )
                )
            for row in upserts:
                stmt = self._insert(table).values(**row)
                s.execute(
                    stmt.on_conflict_do_update(
                        index_elements=["run_id", "visit_key"],
                        set_={k: stmt.excluded[k] for k in row if k not in ("run_id", "visit_key")},
                    )
                )
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

    def upsert_linearity(self, row: dict[str, Any]) -> None:
        """Insert or replace the linearity fit of (run, module, wavelength, sweep)."""
        keys = ("run_id", "module_id", "wavelength_nm", "sweep")
        stmt = self._insert(LinearityCheck.__table__).values(**row)
        stmt = stmt.on_conflict_do_update(
            index_elements=list(keys), set_={k: stmt.excluded[k] for k in row if k not in keys}
        )
        with self.session() as s:
            s.execute(stmt)

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

    # ------------------------------------------------------------ events, alarms
    def add_events(self, events: Sequence[dict[str, Any]]) -> list[int]:
        """Append events (kind, payload, module_id, dive_id, t_unix_s); returns their ids."""
        if not events:
            return []
        with self.session() as s:
            return self._insert_events(s, events)

    @staticmethod
    def _insert_events(s: Session, events: Sequence[dict[str, Any]]) -> list[int]:
        """Add event rows in ``s`` (payloads made valid JSON: no NaN, no infinities); sets each ``id``."""
        objs = []
        for e in events:
            e["payload"] = finite_json(e["payload"])
            objs.append(Event(**{k: v for k, v in e.items() if k != "id"}))
        s.add_all(objs)
        s.flush()
        for e, o in zip(events, objs, strict=True):
            e["id"] = o.id
        return [o.id for o in objs]

    # ------------------------------------------------------------ counters
    def load_counters(self, ingest_id: str) -> dict[str, int]:
        """The counters an ingest saved before (``group.name`` -> value)."""
        with self.read() as s:
            rows = s.execute(
                select(IngestCounter.name, IngestCounter.value).where(IngestCounter.ingest_id == ingest_id)
            )
            return {name: int(value) for name, value in rows}

    def save_counters(self, ingest_id: str, values: dict[str, int]) -> None:
        """Write an ingest's counters (one upsert)."""
        if not values:
            return
        t = now_unix_s()
        rows = [
            {"ingest_id": ingest_id, "name": k[:120], "value": int(v), "updated_unix_s": t}
            for k, v in values.items()
        ]
        stmt = self._insert(IngestCounter.__table__).values(rows)
        stmt = stmt.on_conflict_do_update(
            index_elements=["ingest_id", "name"],
            set_={"value": stmt.excluded.value, "updated_unix_s": stmt.excluded.updated_unix_s},
        )
        with self.session() as s:
            s.execute(stmt)

    def events_after(self, after_id: int, limit: int = 1000) -> list[Event]:
        with self.read() as s:
            return list(s.scalars(select(Event).where(Event.id > after_id).order_by(Event.id).limit(limit)))

    def last_event_id(self) -> int:
        with self.read() as s:
            return int(s.scalar(select(func.max(Event.id))) or 0)

    def active_alarms(self) -> list[Alarm]:
        with self.read() as s:
            return list(s.scalars(select(Alarm).where(Alarm.active.is_(True)).order_by(Alarm.id)))

    def raise_alarm(
        self,
        key: str,
        kind: str,
        severity: str,
        message: str,
        module_id: str | None = None,
        details: dict[str, Any] | None = None,
    ) -> tuple[Alarm, bool]:
        """Raise (or update) the active alarm with ``key``; returns it and whether it is new or changed."""
        t = now_unix_s()
        with self.session() as s:
            alarm = s.scalars(select(Alarm).where(Alarm.key == key, Alarm.active.is_(True))).first()
            if alarm is None:
                alarm = Alarm(
                    key=key,
                    kind=kind,
                    module_id=module_id,
                    severity=severity,
                    message=message,
                    raised_unix_s=t,
                    active=True,
                    details=details or {},
                )
                s.add(alarm)
                s.flush()
                return alarm, True
            changed = alarm.severity != severity or alarm.message != message
            alarm.severity, alarm.message, alarm.details = severity, message, details or {}
            return alarm, changed

    def clear_alarm(self, key: str) -> Alarm | None:
        with self.session() as s:
            alarm = s.scalars(select(Alarm).where(Alarm.key == key, Alarm.active.is_(True))).first()
            if alarm is not None:
                alarm.active = False
                alarm.cleared_unix_s = now_unix_s()
            return alarm

    def ack_alarm(self, alarm_id: int, user: str, note: str = "") -> Alarm | None:
        """Acknowledge an alarm once; the audit log keeps who, when, and the operator's ``note``."""
        with self.session() as s:
            alarm = s.get(Alarm, alarm_id)
            if alarm is None:
                return None
            if alarm.acked_unix_s is None:
                alarm.acked_unix_s, alarm.acked_by = now_unix_s(), user
                s.add(
                    AuditEntry(
                        t_unix_s=now_unix_s(),
                        actor=user,
                        action="alarm.ack",
                        target=f"alarm:{alarm_id}",
                        details={"kind": alarm.kind, "key": alarm.key, "note": note},
                    )
                )
            return alarm

    def audit(self, actor: str, action: str, target: str = "", details: dict[str, Any] | None = None) -> int:
        with self.session() as s:
            entry = AuditEntry(
                t_unix_s=now_unix_s(), actor=actor, action=action, target=target, details=details or {}
            )
            s.add(entry)
            s.flush()
            return entry.id

    # ------------------------------------------------------------ commands
    def create_command(
        self,
        command_id: str,
        module_id: str,
        action: str,
        issued_by: str,
        *,
        payload: dict[str, Any] | None = None,
        target_version: int = 0,
        apply: str = "now",
    ) -> dict[str, Any]:
        """Queue a command (state ``pending``) and record it in the audit log, in one transaction."""
        t = now_unix_s()
        with self.session() as s:
            cmd = CommandRecord(
                id=command_id,
                module_id=module_id,
                action=action,
                target_version=target_version,
                payload=payload or {},
                apply=apply,
                issued_by=issued_by,
                issued_unix_s=t,
                state="pending",
                attempts=0,
                updated_unix_s=t,
            )
            s.add(cmd)
            s.add(
                AuditEntry(
                    t_unix_s=t,
                    actor=issued_by,
                    action=f"command.{action}",
                    target=f"module:{module_id}",
                    details={
                        "command_id": command_id,
                        "target_version": target_version,
                        "apply": apply,
                        "schedule": (payload or {}).get("schedule"),
                    },
                )
            )
            s.flush()
            return command_dict(cmd)

    def command(self, command_id: str) -> dict[str, Any] | None:
        with self.read() as s:
            cmd = s.get(CommandRecord, command_id)
            return command_dict(cmd) if cmd else None

    def commands(
        self, module_id: str | None = None, states: Sequence[str] | None = None, limit: int = 200
    ) -> list[dict[str, Any]]:
        with self.read() as s:
            q = select(CommandRecord)
            if module_id:
                q = q.where(CommandRecord.module_id == module_id)
            if states:
                q = q.where(CommandRecord.state.in_(list(states)))
            return [
                command_dict(c)
                for c in s.scalars(q.order_by(CommandRecord.issued_unix_s.desc()).limit(limit))
            ]

    def mark_command_sent(self, command_id: str) -> None:
        with self.session() as s:
            cmd = s.get(CommandRecord, command_id)
            if cmd is not None:
                cmd.attempts += 1
                cmd.updated_unix_s = now_unix_s()
                if cmd.state == "pending":
                    cmd.state = "sent"

    def update_command(
        self, command_id: str, state: str, reason: str | None, actor: str
    ) -> dict[str, Any] | None:
        """Record a module's answer (audited); returns the command if its state changed."""
        with self.session() as s:
            cmd = s.get(CommandRecord, command_id)
            if cmd is None or COMMAND_STATES.get(state, 0) <= COMMAND_STATES.get(cmd.state, 0):
                return None
            cmd.state, cmd.reason, cmd.updated_unix_s = state, reason, now_unix_s()
            s.add(
                AuditEntry(
                    t_unix_s=now_unix_s(),
                    actor=actor,
                    action=f"command.{state}",
                    target=f"module:{cmd.module_id}",
                    details={"command_id": command_id, "reason": reason, "action": cmd.action},
                )
            )
            return command_dict(cmd)

    def schedule_version(self, module_id: str) -> int:
        """The newest schedule version a module runs or has been sent (not rejected)."""
        with self.read() as s:
            mod = s.get(Module, module_id)
            running = mod.schedule_version if mod else 0
            sent = s.scalar(
                select(func.max(CommandRecord.target_version)).where(
                    CommandRecord.module_id == module_id,
                    CommandRecord.action == "set_schedule",
                    CommandRecord.state != "rejected",
                )
            )
            return max(running or 0, sent or 0)

    def module_exists(self, module_id: str) -> bool:
        with self.read() as s:
            return s.get(Module, module_id) is not None

    # ------------------------------------------------------------ calibrations
    def add_calibration(
        self,
        name: str,
        values: dict[str, Any],
        *,
        actor: str,
        source: str = "",
        valid_from_unix_s: float | None = None,
        valid_to_unix_s: float | None = None,
    ) -> dict[str, Any]:
        """Store a new version of a named calibration (the next integer); audited. Old versions stay."""
        with self.session() as s:
            latest = s.scalar(select(func.max(Calibration.version)).where(Calibration.name == name)) or 0
            cal = Calibration(
                name=name,
                version=latest + 1,
                source=source,
                valid_from_unix_s=valid_from_unix_s,
                valid_to_unix_s=valid_to_unix_s,
                values=values,
                created_unix_s=now_unix_s(),
            )
            s.add(cal)
            s.flush()
            s.add(
                AuditEntry(
                    t_unix_s=now_unix_s(),
                    actor=actor,
                    action="calibration.add",
                    target=f"calibration:{name}@{cal.version}",
                    details={"id": cal.id, "source": source, "values": values},
                )
            )
            return calibration_dict(cal)

    def calibrations(self, name: str | None = None) -> list[dict[str, Any]]:
        with self.read() as s:
            q = select(Calibration)
            if name:
                q = q.where(Calibration.name == name)
            return [calibration_dict(c) for c in s.scalars(q.order_by(Calibration.name, Calibration.version))]

    def calibration(self, ref: int | str) -> dict[str, Any] | None:
        """A calibration by id, by ``name@version``, or by name (its newest version valid now)."""
        with self.read() as s:
            if isinstance(ref, int) or (isinstance(ref, str) and ref.isdigit()):
                c = s.get(Calibration, int(ref))
                return calibration_dict(c) if c else None
            name, _, version = str(ref).partition("@")
            q = select(Calibration).where(Calibration.name == name)
            if version:
                if not version.isdigit():
                    return None
                q = q.where(Calibration.version == int(version))
            else:
                t = now_unix_s()
                q = q.where(
                    (Calibration.valid_from_unix_s.is_(None)) | (Calibration.valid_from_unix_s <= t),
                    (Calibration.valid_to_unix_s.is_(None)) | (Calibration.valid_to_unix_s >= t),
                )
            c = s.scalars(q.order_by(Calibration.version.desc()).limit(1)).first()
            return calibration_dict(c) if c else None

    def use_calibration(self, dive_id: int, run_id: int, calibration_id: int, actor: str) -> None:
        """Record that a dive (and its run) uses a calibration; audited."""
        with self.session() as s:
            s.execute(update(Dive).where(Dive.id == dive_id).values(calibration_id=calibration_id))
            s.execute(
                update(AnalysisRun).where(AnalysisRun.id == run_id).values(calibration_id=calibration_id)
            )
            s.add(
                AuditEntry(
                    t_unix_s=now_unix_s(),
                    actor=actor,
                    action="calibration.use",
                    target=f"dive:{dive_id}",
                    details={"calibration_id": calibration_id, "run_id": run_id},
                )
            )

    # ------------------------------------------------------------ retention
    def purge_frame_files(self, older_than_unix_s: float, modules: Sequence[str] = ()) -> tuple[int, int]:
        """Delete frame files captured before a time (of ``modules`` if given: an ingest that shares
        the data folder purges its own); rows, results and thumbnails stay.

        Returns (files deleted, bytes freed). The image route then says the
        file went to retention.
        """
        n = freed = 0
        with self.read() as s:
            q = select(Frame.path, Frame.size_bytes).where(Frame.captured_unix_s < older_than_unix_s)
            if modules:
                q = q.where(Frame.module_id.in_(list(modules)))
            rows = s.execute(q)
            for path, size in rows:
                try:
                    p = self.files.resolve(path)
                except ValueError:
                    continue
                if p.exists():
                    p.unlink()
                    n += 1
                    freed += int(size or 0)
        return n, freed

    # ------------------------------------------------------------ checks
    def integrity_check(self) -> str:
        """``PRAGMA integrity_check`` on SQLite ("ok" when sound); "ok" elsewhere."""
        if self.engine.dialect.name != "sqlite":
            return "ok"
        with self.engine.connect() as conn:
            return str(conn.exec_driver_sql("PRAGMA integrity_check").scalar())


def _chunks(items: Sequence[Any], n: int) -> Iterator[Sequence[Any]]:
    for i in range(0, len(items), n):
        yield items[i : i + n]
