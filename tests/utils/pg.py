"""A fresh PostgreSQL database per test, on the server named by ``CAMCAL_TEST_PG_URL``.

The variable holds a URL of a role that may create databases, e.g.
``postgresql+psycopg://camcal:camcal@127.0.0.1:5432/postgres`` (``.ci/run``
starts a server and exports it). Without it, the PostgreSQL variants of the
storage and live tests skip.
"""

from __future__ import annotations

import gc
import os
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING

from sqlalchemy import Engine, create_engine, text
from sqlalchemy.engine import make_url
from sqlalchemy.exc import OperationalError
from sqlalchemy.pool import NullPool

from storage.db import make_engine, migrate, normalise_url

if TYPE_CHECKING:
    from tests.utils.live import TcpProxy

PG_ENV = "CAMCAL_TEST_PG_URL"
SKIP_REASON = (
    f"PostgreSQL variant: set {PG_ENV} to a role that may create databases, "
    "e.g. postgresql+psycopg://camcal:camcal@127.0.0.1:5432/postgres (.ci/run does)"
)


def pg_admin_url() -> str | None:
    return os.environ.get(PG_ENV) or None


def _url(admin_url: str, database: str) -> str:
    return make_url(normalise_url(admin_url)).set(database=database).render_as_string(hide_password=False)


def _drop(admin: Engine, name: str, timeout_s: float = 30.0) -> None:
    """Drop database ``name``, ending the sessions a killed test process left open.

    Not ``DROP DATABASE ... WITH (FORCE)``: that refuses, for a role without
    ``pg_signal_backend``, whenever an autovacuum worker happens to be in the
    database. Ending our own role's sessions and then a plain drop works for
    such a role: PostgreSQL itself stops autovacuum workers for a drop.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        with admin.connect() as conn:
            conn.execute(
                text(
                    "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                    "WHERE datname = :name AND usename = current_user AND pid <> pg_backend_pid()"
                ),
                {"name": name},
            )
            try:
                conn.exec_driver_sql(f'DROP DATABASE IF EXISTS "{name}"')
                return
            except OperationalError as exc:  # 55006 object_in_use: a session still closing
                if getattr(exc.orig, "sqlstate", None) != "55006" or time.monotonic() > deadline:
                    raise
        time.sleep(0.2)


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
            # A connection the test left open is collected (and warns) here, in the test that left
            # it, not in whichever later test the garbage collector happens to run in.
            gc.collect()
            _drop(admin, name)
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


@contextmanager
def relayed(url: str) -> Iterator[tuple[str, TcpProxy]]:
    """``url`` reached through a TCP relay the test can cut (a failed database host or network) and
    restore: yields the relayed URL and the relay."""
    from tests.utils.live import TcpProxy

    real = make_url(url)
    proxy = TcpProxy(real.port or 5432)
    try:
        yield real.set(host="127.0.0.1", port=proxy.port).render_as_string(hide_password=False), proxy
    finally:
        proxy.close()


@contextmanager
def served_on_a_relayed_database(
    data: Path, pg_template: tuple[str, str] | None
) -> Iterator[tuple[str, TcpProxy]]:
    """``camcal serve`` of ``data`` on a fresh PostgreSQL database reached through a relay the test
    can cut (`relayed`): yields the server's base URL and the relay; skips without PostgreSQL."""
    import pytest

    from tests.utils.system import camcal_serve

    if pg_template is None:
        pytest.skip(SKIP_REASON)
    with (
        fresh_database(*pg_template) as url,
        relayed(url) as (relayed_url, proxy),
        camcal_serve(data, "--db-url", relayed_url) as (base, _),
    ):
        yield base, proxy
