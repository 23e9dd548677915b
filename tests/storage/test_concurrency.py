"""Several processes on one database: one dive per name, one live run per dive, migrations that queue."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from storage import queries
from storage.db import current_revision, head_revision, make_engine, migrate
from storage.models import AnalysisRun, Dive
from storage.store import Store
from tests.utils.pg import SKIP_REASON, fresh_database, pg_admin_url

N = 6


def all_at_once(fn: Callable[[int], Any], n: int = N) -> list[Any]:
    """Run ``fn(i)`` in ``n`` threads released together; re-raise the first error."""
    barrier = threading.Barrier(n)
    out: list[Any] = [None] * n
    errors: list[BaseException] = []

    def run(i: int) -> None:
        try:
            barrier.wait(10)
            out[i] = fn(i)
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=run, args=(i,)) for i in range(n)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    if errors:
        raise errors[0]
    return out


@pytest.fixture
def stores(tmp_path: Path, db_url: str | None) -> Iterator[list[Store]]:
    """``N`` stores on one database, each with its own engine, as ``N`` ingest processes would have."""
    first = Store.open(tmp_path / "data", db_url, sqlite_synchronous="NORMAL")
    others = [
        Store.open(tmp_path / "data", db_url, run_migrations=False, sqlite_synchronous="NORMAL")
        for _ in range(N - 1)
    ]
    yield [first, *others]
    for s in [first, *others]:
        s.close()


def test_a_named_dive_and_its_live_run_are_created_once(stores: list[Store]) -> None:
    def start(i: int) -> tuple[int, int]:
        dive = stores[i].current_dive(name="trident-0007", setup={"who": i})
        run = stores[i].analysis_run(dive.id, "live", software_version="x")
        return dive.id, run.id

    got = all_at_once(start)
    assert len(set(got)) == 1
    with stores[0].read() as s:
        assert len(s.scalars(select(Dive)).all()) == 1
        assert len(s.scalars(select(AnalysisRun).where(AnalysisRun.kind == "live")).all()) == 1


def test_processes_without_a_dive_name_agree_on_one_open_dive(stores: list[Store]) -> None:
    ids = all_at_once(lambda i: stores[i].current_dive(create=True).id)
    assert len(set(ids)) == 1
    stores[0].end_dive(ids[0])
    assert stores[1].current_dive(create=False) is None
    assert stores[2].current_dive(name="trident-0007", create=False) is None


def test_a_second_live_run_of_a_dive_is_refused_by_the_database(stores: list[Store]) -> None:
    from sqlalchemy.exc import IntegrityError

    dive = stores[0].current_dive(name="d")
    stores[0].analysis_run(dive.id, "live")
    with pytest.raises(IntegrityError), stores[0].session() as s:
        s.add(AnalysisRun(dive_id=dive.id, kind="live", created_unix_s=0.0))
    stores[0].analysis_run(dive.id, "reanalysis")
    stores[0].analysis_run(dive.id, "reanalysis")  # any number of re-analyses


def test_modules_touched_at_once_exist_once(stores: list[Store]) -> None:
    all_at_once(lambda i: stores[i].touch_module("A", boot=f"b{i}"))
    assert stores[0].call(queries.module_exists, "A")


@pytest.fixture(params=["sqlite", "postgresql"])
def empty_db(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'empty.db'}"
        return
    admin = pg_admin_url()
    if admin is None:
        pytest.skip(SKIP_REASON)
    with fresh_database(admin) as url:
        yield url


def test_migration_0002_keeps_the_oldest_live_run_of_a_dive(empty_db: str) -> None:
    engine = make_engine(empty_db, sqlite_synchronous="NORMAL")
    try:
        migrate(engine, "0001")
        with engine.begin() as conn:
            conn.exec_driver_sql(
                "INSERT INTO dives (id, name, started_unix_s, notes, setup) VALUES (1, 'd', 0, '', '{}')"
            )
            for i in (1, 2, 3):
                conn.exec_driver_sql(
                    "INSERT INTO analysis_runs (id, dive_id, kind, label, calibration, software_version,"
                    " created_unix_s, status, n_frames)"
                    f" VALUES ({i}, 1, 'live', '', '{{}}', '', 0, 'done', 0)"
                )
        migrate(engine)
        assert current_revision(engine) == head_revision()
        with engine.connect() as conn:
            kinds = dict(conn.exec_driver_sql("SELECT id, kind FROM analysis_runs ORDER BY id").all())
        assert kinds == {1: "live", 2: "live-extra", 3: "live-extra"}
    finally:
        engine.dispose()


def test_processes_migrating_one_postgresql_database_at_once_all_succeed() -> None:
    admin = pg_admin_url()
    if admin is None:
        pytest.skip(SKIP_REASON)
    with fresh_database(admin) as url:
        engines = [make_engine(url) for _ in range(4)]
        try:
            all_at_once(lambda i: migrate(engines[i]), n=4)
            assert {current_revision(e) for e in engines} == {head_revision()}
        finally:
            for e in engines:
                e.dispose()


FIRST_USE = """
import sys, threading, time, warnings
from pathlib import Path
from sqlalchemy.sql import annotation

warnings.simplefilter("error")


class SlowToFinish(dict):
    # SQLAlchemy registers each new annotated class before it sets the class's
    # caching attributes; a pause there makes that window wide enough to hit.
    def __setitem__(self, key, value):
        super().__setitem__(key, value)
        time.sleep(0.2)


annotation.annotated_classes = SlowToFinish(annotation.annotated_classes)
from storage.store import Store

root = Path(sys.argv[1])
stores = [Store.open(root, None)] + [Store.open(root, None, run_migrations=False) for _ in range(5)]
barrier, errors = threading.Barrier(6), []


def run(i):
    try:
        barrier.wait(10)
        stores[i].current_dive(create=True)
    except BaseException as exc:
        errors.append(repr(exc))


threads = [threading.Thread(target=run, args=(i,)) for i in range(6)]
for t in threads:
    t.start()
for t in threads:
    t.join(60)
print(errors[0] if errors else "ok")
"""


def test_the_open_dive_is_found_by_threads_of_a_fresh_process_at_once(tmp_path: Path) -> None:
    """The first open-dive lookup of a process, from six threads at once, on SQLite.

    A clean clone's CI once failed here: the write lock SQLite's get-or-create
    takes was an ORM UPDATE, and the first one built in a process raced
    SQLAlchemy's half-registered class (SAWarning, then a KeyError).
    """
    repo = Path(__file__).resolve().parents[2]
    done = subprocess.run(
        [sys.executable, "-c", FIRST_USE, str(tmp_path / "data")],
        cwd=repo,
        env={**os.environ, "PYTHONPATH": str(repo)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() == "ok"
