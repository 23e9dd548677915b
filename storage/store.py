"""The store: every write of camcal goes through here; the reads are `storage.queries`.

One writer (the ingest's store thread, or an import) and any number of
readers (the server). Batches are written in one transaction each. The
writes are split by what they write about: `storage.analysis_writes`,
`storage.operations_writes`; a read runs with ``store.call(queries.fn, ...)``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

from sqlalchemy import Table, and_, case, delete, func, insert, select, true, update
from sqlalchemy.engine import make_url
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session

from camcal.core.clockmap import ModuleClock
from camcal.core.events import Event
from storage import queries
from storage.analysis_writes import AnalysisWrites
from storage.base import now_unix_s
from storage.db import DataPaths, database_unusable, error_line, make_engine, migrate
from storage.files import FrameFiles
from storage.models import (
    Dive,
    Frame,
    Gap,
    IngestCounter,
    Module,
    ModuleClockRecord,
    SensorBatch,
    SensorSample,
)
from storage.operations_writes import COMMAND_STATES, OperationsWrites
from storage.queries.divestate import DiveRules, DiveState, dive_state

__all__ = [
    "COMMAND_STATES",
    "DIVE_LOCK_KEY",
    "BatchOutcome",
    "DiveChoice",
    "DiveRules",
    "FrameRow",
    "SensorBatchRow",
    "Store",
    "now_unix_s",
]

#: Key of the advisory lock that serialises choosing (or creating) the open dive.
DIVE_LOCK_KEY = 0x63616D64697665  # "camdive"


@dataclass(frozen=True)
class DiveChoice:
    """The dive a start records into, whether it holds no frame yet, and the dive that start recorded
    as ended (its name and why) before beginning this one."""

    dive: Dive
    new: bool
    ended: tuple[str, DiveState] | None = None
    #: Why the named dive had ended, when a start named it and so opened it again.
    reopened: str | None = None


def _on_ship(clock: ModuleClock | None, t_unix_s: float | None) -> float | None:
    return None if clock is None or t_unix_s is None else clock.ship(t_unix_s)


def _open_dive(s: Session) -> Dive | None:
    return s.scalars(
        select(Dive).where(Dive.ended_unix_s.is_(None)).order_by(Dive.id.desc()).limit(1)
    ).first()


def _new_dive_name(s: Session, t: float) -> str:
    """``dive-YYYYMMDD-HHMMSS`` (UTC), with a suffix if a dive began in the same second."""
    base = time.strftime("dive-%Y%m%d-%H%M%S", time.gmtime(t))
    name, k = base, 1
    while s.scalar(select(Dive.id).where(Dive.name == name)) is not None:
        k += 1
        name = f"{base}-{k}"
    return name


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
    content_sha256: str | None = None  # `camcal.core.wire.content_sha256` of a received message
    #: The capture time on the ship's clock (the module's mapped onto it: `camcal.core.clockmap`);
    #: None where no mapping was known (an import): the capture time stands for it.
    captured_ship_unix_s: float | None = None

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
    #: One part of a large batch, stored a part per turn: (first row, rows, rows of the batch); the
    #: batch is complete (acknowledged) with its last part. None: the whole batch.
    part: tuple[int, int, int] | None = None
    content_sha256: str | None = None  # `camcal.core.wire.content_sha256` of the message
    #: The module's clock mapped onto the ship's: each sample's time on the ship's clock too.
    clock: ModuleClock | None = None


@dataclass
class BatchOutcome:
    """What a batch commit did: ids of new frames by (module, boot, seq); duplicates skipped."""

    new_frames: dict[tuple[str, str, int], int]
    duplicate_frames: list[tuple[str, str, int]]
    new_sensor_batches: list[tuple[str, str, int]]
    duplicate_sensor_batches: list[tuple[str, str, int]]
    events: list[Event] = field(default_factory=list)  # stored with the frames, ``id`` set


class StoreUnavailable(RuntimeError):
    """The store's database cannot be opened: the message names it and says what to do."""

    def __init__(self, where: str, exc: BaseException) -> None:
        why = error_line(exc)
        if database_unusable(exc):
            advice = "check that the database runs and the URL is right (`camcal doctor`)"
        else:  # it answers, but what it holds is not a camcal database
            advice = (
                "the file is damaged or not camcal's: move it aside and start again (the frame files "
                "are kept, and `camcal import` of the modules' SD cards rebuilds the dives), or restore "
                "it from a backup"
            )
        super().__init__(f"the database {where} cannot be opened ({why}): {advice}")


class Store(AnalysisWrites, OperationsWrites):
    """The database (any SQLAlchemy URL; SQLite by default) and the frame files."""

    @classmethod
    def open(
        cls,
        data_dir: Path,
        url: str | None = None,
        *,
        run_migrations: bool = True,
        sqlite_synchronous: str = "FULL",
    ) -> Store:
        """Open (and by default migrate) the store of a data folder.

        Raises `StoreUnavailable` (its message says what to do) when the database cannot be
        reached or read: not running, a wrong URL, a damaged or foreign SQLite file.
        """
        paths = DataPaths(Path(data_dir))
        paths.root.mkdir(parents=True, exist_ok=True)
        engine = make_engine(url or paths.sqlite_url(), sqlite_synchronous=sqlite_synchronous)
        try:
            if run_migrations:
                migrate(engine)
            else:
                with engine.connect() as conn:
                    conn.exec_driver_sql("SELECT 1")
        except DBAPIError as exc:
            engine.dispose()
            where = make_url(url).render_as_string(hide_password=True) if url else str(paths.db_file)
            raise StoreUnavailable(where, exc) from exc
        return cls(engine, FrameFiles(paths.root))

    # ------------------------------------------------------------ dives
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
        self,
        *,
        create: bool = True,
        name: str | None = None,
        setup: dict[str, Any] | None = None,
        rules: DiveRules | None = None,
    ) -> Dive | None:
        """The dive called ``name`` if one is given, else the open dive (not ended), the most recent first.

        Created if missing and ``create``; then an open dive that is over (`dive_to_record`) is
        recorded as ended and a new one begins. Safe under concurrency: processes asking at once
        for a named dive all get the same row (the name is unique), and the choice of the open
        dive is serialised by a lock.
        """
        if name is not None:
            return self.open_dive(name, setup) if create else self.call(queries.dive_by_name, name)
        if create:
            return self.dive_to_record(setup=setup, rules=rules).dive
        with self.session() as s:
            return _open_dive(s)

    def dive_to_record(
        self, name: str | None = None, setup: dict[str, Any] | None = None, rules: DiveRules | None = None
    ) -> DiveChoice:
        """The dive a start records into: ``name`` (created if new), else the open dive, else a new one.

        An open dive that is over by what its modules did (back on deck and signed off, or quiet
        on deck: `storage.queries.divestate`) is recorded as ended, with its reason, and a new
        dive begins; a dive still in the water is continued (a restart in the middle of a dive).
        """
        if name is not None:  # named: recorded into, an ended one opened again (it said why it ended)
            dive = self.open_dive(name, setup)
            reopened = dive.end_reason or ("ended" if dive.ended_unix_s else None)
            if dive.ended_unix_s:
                with self.session() as s:
                    s.execute(
                        update(Dive).where(Dive.id == dive.id).values(ended_unix_s=None, end_reason=None)
                    )
                dive.ended_unix_s, dive.end_reason = None, None
            n = (self.call(queries.dive_record, dive.id) or {}).get("n_frames", 0)
            return DiveChoice(dive, new=n == 0, reopened=reopened)
        with self.session() as s:
            self._serialise(s, DIVE_LOCK_KEY)
            current = _open_dive(s)
            ended = None
            if current is not None:
                state = dive_state(s, current, rules)
                if state.state == "ended":
                    current.ended_unix_s = state.ended_unix_s or now_unix_s()
                    current.end_reason = state.reason
                    ended = (current.name, state)
                else:
                    n = s.scalar(select(func.count(Frame.id)).where(Frame.dive_id == current.id)) or 0
                    return DiveChoice(current, new=n == 0)
            t = now_unix_s()
            dive = Dive(
                name=_new_dive_name(s, t),
                started_unix_s=t,
                notes="",
                setup=setup or {},
            )
            s.add(dive)
            s.flush()
            return DiveChoice(dive, new=True, ended=ended)

    def create_dive(
        self, name: str, setup: dict[str, Any] | None = None, started_unix_s: float | None = None
    ) -> Dive:
        with self.session() as s:
            dive = Dive(name=name, started_unix_s=started_unix_s or now_unix_s(), notes="", setup=setup or {})
            s.add(dive)
            s.flush()
            return dive

    def adopt_dive_setup(self, dive_id: int, setup: dict[str, Any]) -> None:
        """Give a dive that has no setup of its own this one (an imported frame set's setup.json)."""
        with self.session() as s:
            dive = s.get(Dive, dive_id)
            if dive is not None and not dive.setup:
                dive.setup = setup

    def end_dive(self, dive_id: int, t: float | None = None, reason: str | None = None) -> None:
        """Record a dive as ended at ``t`` (now) and why."""
        with self.session() as s:
            s.execute(
                update(Dive)
                .where(Dive.id == dive_id)
                .values(ended_unix_s=t or now_unix_s(), end_reason=(reason or "")[:300] or None)
            )

    # ------------------------------------------------------------ modules
    def touch_module(self, module_id: str, *, seen_unix_s: float | None = None, **values: Any) -> None:
        """Create or update a module row (last seen, boot, schedule, distance...)."""
        t = seen_unix_s or now_unix_s()
        changes: dict[str, Any] = {k: v for k, v in values.items() if v is not None}
        # last seen never goes back (a late heartbeat of another ingest); one UPDATE, no ORM object
        changes["last_seen_unix_s"] = case((Module.last_seen_unix_s < t, t), else_=Module.last_seen_unix_s)
        with self.session() as s:
            self._ensure_modules(s, [module_id], t)
            s.execute(update(cast(Table, Module.__table__)).where(Module.id == module_id).values(**changes))

    def record_module_clock(
        self, dive_id: int, module_id: str, boot: str, clock: ModuleClock, n_readings: int, t: float
    ) -> None:
        """Keep a module's clock of one boot as the ship maps it (its newest offset; one row a boot)."""
        values = {
            "dive_id": dive_id,
            "rate": clock.rate,
            "module_at_unix_s": clock.module_at_unix_s,
            "real_at_unix_s": clock.real_at_unix_s,
            "offset_s": clock.offset_s if n_readings else None,
            "n_readings": n_readings,
            "updated_unix_s": t,
        }
        stmt = self._insert(ModuleClockRecord.__table__).values(
            module_id=module_id, boot=boot, first_unix_s=t, **values
        )
        stmt = stmt.on_conflict_do_update(index_elements=["module_id", "boot"], set_=values)
        with self.session() as s:
            s.execute(stmt)

    def _ensure_modules(self, s: Session, module_ids: Iterable[str], t: float) -> None:
        """Module rows for ``module_ids`` (one statement; a row another process just added is kept)."""
        ids = sorted(set(module_ids))
        if ids:
            s.execute(  # executemany of one cached statement (a multi-row VALUES is compiled each time)
                self._insert(Module.__table__).on_conflict_do_nothing(index_elements=["id"]),
                [{"id": m, "first_seen_unix_s": t, "last_seen_unix_s": t} for m in ids],
            )

    # ------------------------------------------------------------ ingest
    def commit_batch(
        self,
        dive_id: int,
        frames: Sequence[FrameRow],
        sensors: Sequence[SensorBatchRow] = (),
        frame_event: Callable[[FrameRow, int], Event] | None = None,
        events: Sequence[Event] = (),
        counters: Callable[[BatchOutcome], tuple[str, dict[str, int]]] | None = None,
    ) -> BatchOutcome:
        """Insert frames and sensor batches in one transaction, skipping any already stored.

        (module, boot, seq) is unique for frames and for sensor batches, so a
        resend after a lost acknowledgement changes nothing. ``frame_event``
        makes the event of each new frame (given the row and its id); the
        events are written in the same transaction, so a crash can never
        leave a stored frame without its event. ``counters`` gives, from what
        was stored, an ingest's id and its counters counting it: they are
        written in the same transaction too, so that the counts are never
        behind the data after a crash.
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
                    if d["captured_ship_unix_s"] is None:  # no mapping known: its own time stands
                        d["captured_ship_unix_s"] = d["captured_unix_s"]
                    rows.append(d)
                stmt = (  # executemany with RETURNING: a skipped duplicate returns no row
                    self._insert(Frame.__table__)
                    .on_conflict_do_nothing(index_elements=["module_id", "boot", "seq"])
                    .returning(Frame.id, Frame.module_id, Frame.boot, Frame.seq)
                )
                for fid, mid, boot, seq in s.execute(stmt, rows):
                    new_frames[(mid, boot, int(seq))] = int(fid)
            for b in sensors:
                batch_id = self._sensor_batch(s, b)
                if batch_id is None:
                    continue
                new_sensors.append((b.module_id, b.boot, b.seq))
                if b.samples:
                    s.execute(
                        insert(SensorSample),
                        [
                            {
                                **smp,
                                "module_id": b.module_id,
                                "dive_id": dive_id,
                                "batch_id": batch_id,
                                "t_ship_unix_s": _on_ship(b.clock, smp.get("t_unix_s")),
                            }
                            for smp in b.samples
                        ],
                    )
            stored = list(events)
            if frame_event is not None and new_frames:
                for f in frames:
                    fid = new_frames.get((f.module_id, f.boot, f.seq))
                    if fid is not None:
                        stored.append(frame_event(f, fid))
            if stored:
                self._insert_events(s, stored)
            keys = [(f.module_id, f.boot, f.seq) for f in frames]
            skeys = [(b.module_id, b.boot, b.seq) for b in sensors]
            outcome = BatchOutcome(
                new_frames=new_frames,
                duplicate_frames=[k for k in keys if k not in new_frames],
                new_sensor_batches=new_sensors,
                duplicate_sensor_batches=[k for k in skeys if k not in new_sensors],
                events=stored,
            )
            if counters is not None:
                self._save_counters(s, *counters(outcome))
        return outcome

    def _sensor_batch(self, s: Session, b: SensorBatchRow) -> int | None:
        """The row of a sensor batch (or of a part of one) to store samples under; None for a batch
        stored before (a resend). A first part starts an incomplete batch (replacing one a failure
        left behind), the last part completes it."""
        key = (SensorBatch.module_id == b.module_id, SensorBatch.boot == b.boot, SensorBatch.seq == b.seq)
        first, n, total = b.part or (0, len(b.samples), len(b.samples))
        last = first + n >= total
        if first > 0:  # a later part of a batch whose first part is stored
            batch_id = s.scalar(select(SensorBatch.id).where(*key, SensorBatch.complete.is_(False)))
            if batch_id is None:
                raise RuntimeError(
                    f"sensor batch {b.module_id}/{b.boot}/{b.seq}: part {first} without its first"
                )
            if last:
                s.execute(update(SensorBatch).where(SensorBatch.id == batch_id).values(complete=True))
            return int(batch_id)
        self._remove_incomplete(s, and_(*key))
        stmt = (
            self._insert(SensorBatch.__table__)
            .values(
                module_id=b.module_id,
                boot=b.boot,
                seq=b.seq,
                count=total,
                received_unix_s=b.received_unix_s,
                sha256=b.sha256,
                content_sha256=b.content_sha256,
                complete=last,
            )
            .on_conflict_do_nothing(index_elements=["module_id", "boot", "seq"])
            .returning(SensorBatch.id)
        )
        row = s.execute(stmt).first()
        return None if row is None else int(row[0])

    @staticmethod
    def _remove_incomplete(s: Session, where: Any) -> int:
        """Delete incomplete sensor batches (``where``) and their samples; how many."""
        ids = list(s.scalars(select(SensorBatch.id).where(where, SensorBatch.complete.is_(False))))
        if ids:
            s.execute(delete(SensorSample).where(SensorSample.batch_id.in_(ids)))
            s.execute(delete(SensorBatch).where(SensorBatch.id.in_(ids)))
        return len(ids)

    def remove_incomplete_sensor_batches(self, modules: Sequence[str] = ()) -> int:
        """Sensor batches a stopped ingest left incomplete (never acknowledged: their modules resend
        them), with their samples; with ``modules``, only theirs. How many."""
        with self.session() as s:
            where = SensorBatch.module_id.in_(modules) if modules else true()
            return self._remove_incomplete(s, where)

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

    def add_events(self, events: Sequence[Event]) -> list[int]:
        """Append events to the event log; sets each one's ``id`` and returns them."""
        if not events:
            return []
        with self.session() as s:
            return self._insert_events(s, events)

    def save_counters(self, ingest_id: str, values: dict[str, int]) -> None:
        """Write an ingest's counters (one upsert)."""
        with self.session() as s:
            self._save_counters(s, ingest_id, values)

    def _save_counters(self, s: Session, ingest_id: str, values: dict[str, int]) -> None:
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
        s.execute(stmt)
