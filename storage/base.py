"""The store's base: the engine, transactions, and ``call`` (run a read of `storage.queries`)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Concatenate, ParamSpec, TypeVar, cast

from sqlalchemy import Engine, Table, insert, text
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session, sessionmaker

from camcal.core.events import Event, finite_json
from storage.files import FrameFiles
from storage.models import Dive
from storage.models import Event as EventRow

P = ParamSpec("P")
R = TypeVar("R")


def now_unix_s() -> float:
    return time.time()


class StoreBase:
    """The database (any SQLAlchemy URL; SQLite by default) and the frame files."""

    def __init__(self, engine: Engine, files: FrameFiles) -> None:
        self.engine = engine
        self.files = files
        self._sessions = sessionmaker(engine, expire_on_commit=False)

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

    def call(self, fn: Callable[Concatenate[Session, P], R], *args: P.args, **kwargs: P.kwargs) -> R:
        """``fn(session, *args, **kwargs)`` in a read session: the one way to run a query of
        `storage.queries` (``store.call(queries.runs, dive_id)``). It blocks: call it from a thread
        (a plain ``def`` route runs in FastAPI's threadpool), never on an event loop."""
        with self._sessions() as s:
            return fn(s, *args, **kwargs)

    # ------------------------------------------------------------ helpers
    @staticmethod
    def _insert_events(s: Session, events: Sequence[Event]) -> list[int]:
        """Add event rows in ``s`` (payloads made valid JSON: no NaN, no infinities); sets each ``id``."""
        if not events:
            return []
        rows = [
            {
                "kind": str(e.kind),
                "payload": finite_json(e.payload),
                "module_id": e.module,
                "dive_id": e.dive_id,
                "t_unix_s": e.t,
            }
            for e in events
        ]
        # One cached Core statement, executemany (no ORM objects, no flush); the ids come back in
        # the order of the rows, which is the order of the event log.
        stmt = insert(cast(Table, EventRow.__table__)).returning(EventRow.id, sort_by_parameter_order=True)
        ids = [int(i) for i in s.execute(stmt, rows).scalars()]
        for e, i in zip(events, ids, strict=True):
            e.id = i
        return ids

    def _upsert_many(
        self, s: Session, table: Any, rows: Sequence[dict[str, Any]], keys: Sequence[str]
    ) -> None:
        """Insert ``rows``, or update the columns they carry where the unique ``keys`` exist: one
        statement per set of columns, run over its rows (executemany), not one built per row.
        Rows with the same keys are merged first, later values winning, as if run one by one
        (PostgreSQL refuses one statement that updates a row twice)."""
        merged: dict[tuple[Any, ...], dict[str, Any]] = {}
        for row in rows:
            key = tuple(row[k] for k in keys)
            merged[key] = {**merged[key], **row} if key in merged else dict(row)
        groups: dict[frozenset[str], list[dict[str, Any]]] = {}
        for row in merged.values():
            groups.setdefault(frozenset(row), []).append(row)
        for cols, group in groups.items():
            stmt = self._insert(table)
            stmt = stmt.on_conflict_do_update(
                index_elements=list(keys),
                set_={k: stmt.excluded[k] for k in sorted(cols) if k not in keys},
            )
            s.execute(stmt, group)

    def _insert(self, table: Any) -> Any:
        name = self.engine.dialect.name
        if name == "sqlite":
            return sqlite.insert(table)
        if name == "postgresql":
            return postgresql.insert(table)
        raise NotImplementedError(f"conflict-free inserts are written for SQLite and PostgreSQL, not {name}")

    def _serialise(self, s: Session, key: int) -> None:
        """Hold a lock until ``s`` commits, so get-or-create steps of several processes queue.

        PostgreSQL: a transaction-level advisory lock on ``key``. SQLite: a
        write statement that changes nothing takes the database's write lock.
        Both are plain SQL text: an ORM ``update(Dive)`` here was the first
        annotated UPDATE of a process, and SQLAlchemy registers the class it
        makes for that before finishing it, so threads asking at once saw it
        half-built (an SAWarning, then a KeyError).
        """
        if self.engine.dialect.name == "postgresql":
            s.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": key})
        else:
            s.execute(text(f"UPDATE {Dive.__tablename__} SET name = name WHERE 0"))

    def integrity_check(self) -> str:
        """``PRAGMA integrity_check`` on SQLite ("ok" when sound); "ok" elsewhere."""
        if self.engine.dialect.name != "sqlite":
            return "ok"
        with self.engine.connect() as conn:
            return str(conn.exec_driver_sql("PRAGMA integrity_check").scalar())
