"""Engines and migrations: SQLite in WAL mode by default, PostgreSQL for a shared store.

Any SQLAlchemy URL is accepted; ``postgresql://`` (and ``postgres://``) URLs
use the psycopg 3 driver. Several processes may migrate one PostgreSQL
database at once: they queue on an advisory lock, so the first one upgrades
and the others find it done.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.engine import make_url

MIGRATIONS = Path(__file__).with_name("migrations")
DB_FILE = "camcal.db"
#: Key of the PostgreSQL advisory lock held while migrating (any constant unique to camcal).
MIGRATION_LOCK_KEY = 0x63616D63616C  # "camcal"


@dataclass(frozen=True)
class DataPaths:
    """Where a data folder keeps things."""

    root: Path

    @property
    def db_file(self) -> Path:
        return self.root / DB_FILE

    @property
    def frames(self) -> Path:
        return self.root / "frames"

    @property
    def thumbs(self) -> Path:
        return self.root / "thumbs"

    @property
    def exports(self) -> Path:
        return self.root / "exports"

    def sqlite_url(self) -> str:
        return f"sqlite:///{self.db_file}"


def make_engine(url: str, *, sqlite_synchronous: str = "FULL", echo: bool = False) -> Engine:
    """An engine for ``url``; SQLite gets WAL, foreign keys and a busy timeout.

    WAL lets the server read while the ingest writes. ``synchronous=FULL``
    makes every commit durable across a power cut as well as a killed
    process, at the price of one fsync per commit: the ingest batches its
    commits, so this costs little (``NORMAL`` is allowed for tests).
    """
    if url.startswith("sqlite"):
        engine = create_engine(
            url, echo=echo, connect_args={"timeout": 30, "check_same_thread": False}, pool_pre_ping=True
        )
        if sqlite_synchronous not in ("OFF", "NORMAL", "FULL", "EXTRA"):
            raise ValueError(f"sqlite_synchronous must be OFF/NORMAL/FULL/EXTRA, got {sqlite_synchronous!r}")

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute(f"PRAGMA synchronous={sqlite_synchronous}")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute("PRAGMA busy_timeout=30000")
            cur.close()

        return engine
    return create_engine(normalise_url(url), echo=echo, pool_pre_ping=True)


def normalise_url(url: str) -> str:
    """``postgresql://`` and ``postgres://`` URLs get the psycopg 3 driver (psycopg2 is not used)."""
    parsed = make_url(
        url.replace("postgres://", "postgresql://", 1) if url.startswith("postgres://") else url
    )
    if parsed.drivername == "postgresql":
        parsed = parsed.set(drivername="postgresql+psycopg")
    return parsed.render_as_string(hide_password=False)


def alembic_config(url: str | None = None) -> Config:
    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    if url:
        cfg.set_main_option("sqlalchemy.url", url.replace("%", "%%"))
    return cfg


def migrate(engine: Engine, revision: str = "head") -> None:
    """Bring the database to ``revision`` (the newest by default)."""
    cfg = alembic_config()
    with engine.begin() as conn:
        if conn.dialect.name == "postgresql":
            # DDL is transactional in PostgreSQL: a second process waits here, then sees the head.
            conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": MIGRATION_LOCK_KEY})
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, revision)


def current_revision(engine: Engine) -> str | None:
    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()


def head_revision() -> str | None:
    return ScriptDirectory.from_config(alembic_config()).get_current_head()


def database_unusable(exc: BaseException) -> bool:
    """Whether ``exc`` says the database cannot be used now, whatever was asked of it: not running,
    unreachable, locked, its disk full, no connection free (SQLAlchemy's `OperationalError`,
    `InterfaceError`, pool timeout, a driver's disconnect; sqlite3's own `OperationalError`)."""
    import sqlite3

    from sqlalchemy.exc import DBAPIError, InterfaceError, OperationalError
    from sqlalchemy.exc import TimeoutError as PoolTimeout

    return isinstance(exc, OperationalError | InterfaceError | PoolTimeout | sqlite3.OperationalError) or (
        isinstance(exc, DBAPIError) and exc.connection_invalidated
    )


def error_line(exc: BaseException) -> str:
    """The first line of what went wrong, at most 200 characters: the driver's own message for a
    database error (without SQLAlchemy's statement and link), else the exception's."""
    text = str(getattr(exc, "orig", None) or exc).strip()
    return (text.splitlines() or [type(exc).__name__])[0][:200]


def database_unavailable(exc: BaseException) -> str | None:
    """What to tell a person when ``exc`` says the database cannot be used now (`database_unusable`),
    else None (a fault of the request)."""
    if not database_unusable(exc):
        return None
    why = error_line(exc)
    return (
        f"the database cannot be used now ({why}). Nothing is lost: the modules keep their frames "
        "and the ingest its results until it can store them. Check that the database is running "
        "(`camcal doctor`); this page retries by itself."
    )
