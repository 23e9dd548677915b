"""A fresh PostgreSQL database per test, on the server named by ``CAMCAL_TEST_PG_URL``.

The variable holds a URL of a role that may create databases, e.g.
``postgresql+psycopg://camcal:camcal@127.0.0.1:5432/postgres`` (``.ci/run``
starts a server and exports it). Without it, the PostgreSQL variants of the
storage and live tests skip.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import create_engine
from sqlalchemy.engine import make_url
from sqlalchemy.pool import NullPool

from storage.db import make_engine, migrate, normalise_url

PG_ENV = "CAMCAL_TEST_PG_URL"
SKIP_REASON = (
    f"PostgreSQL variant: set {PG_ENV} to a role that may create databases, "
    "e.g. postgresql+psycopg://camcal:camcal@127.0.0.1:5432/postgres (.ci/run does)"
)


def pg_admin_url() -> str | None:
    return os.environ.get(PG_ENV) or None


def _url(admin_url: str, database: str) -> str:
    return make_url(normalise_url(admin_url)).set(database=database).render_as_string(hide_password=False)


@contextmanager
def fresh_database(admin_url: str, template: str | None = None) -> Iterator[str]:
    """Create a database (empty, or a copy of ``template``), yield its URL, drop it.

    The drop closes any connection a killed process left behind.
    """
    name = f"camcal_test_{uuid.uuid4().hex[:16]}"
    admin = create_engine(normalise_url(admin_url), isolation_level="AUTOCOMMIT", poolclass=NullPool)
    try:
        with admin.connect() as conn:
            conn.exec_driver_sql(
                f'CREATE DATABASE "{name}"' + (f' TEMPLATE "{template}"' if template else "")
            )
        try:
            yield _url(admin_url, name)
        finally:
            with admin.connect() as conn:
                conn.exec_driver_sql(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
    finally:
        admin.dispose()


@contextmanager
def migrated_template(admin_url: str) -> Iterator[str]:
    """A database migrated to the head once, to copy per test (faster than migrating each one)."""
    with fresh_database(admin_url) as url:
        engine = make_engine(url)
        try:
            migrate(engine)
        finally:
            engine.dispose()
        yield make_url(url).database or ""
