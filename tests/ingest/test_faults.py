"""Whose fault a failure to store is: the ship's failures are never held against a message."""

from __future__ import annotations

import errno
import sqlite3

import pytest
from sqlalchemy import create_engine, text
from sqlalchemy.exc import IntegrityError, OperationalError

from ingest.faults import ships_fault


def raised(fn) -> BaseException:
    try:
        fn()
    except BaseException as exc:
        return exc
    raise AssertionError("nothing raised")


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EROFS, errno.EIO, errno.EACCES, errno.EDQUOT])
def test_a_disk_that_is_full_read_only_or_failing_is_the_ships_fault(code: int) -> None:
    assert ships_fault(OSError(code, "from the disk"))


def test_the_cause_is_looked_for_along_the_chain() -> None:
    def wrapped() -> None:
        try:
            raise OSError(errno.ENOSPC, "No space left on device")
        except OSError as exc:
            raise RuntimeError("writing a frame failed") from exc

    assert ships_fault(raised(wrapped))


def test_a_locked_sqlite_database_is_the_ships_fault(tmp_path) -> None:
    path = tmp_path / "locked.db"
    holder = sqlite3.connect(path, isolation_level=None)
    holder.execute("CREATE TABLE t (x)")
    holder.execute("BEGIN IMMEDIATE")
    engine = create_engine(f"sqlite:///{path}", connect_args={"timeout": 0.05})
    try:

        def write() -> None:
            with engine.begin() as conn:
                conn.execute(text("INSERT INTO t VALUES (1)"))

        exc = raised(write)
        assert isinstance(exc, OperationalError) and "locked" in str(exc)
        assert ships_fault(exc)
    finally:
        holder.execute("ROLLBACK")
        holder.close()
        engine.dispose()


def test_what_the_data_did_is_not_the_ships_fault(tmp_path) -> None:
    engine = create_engine(f"sqlite:///{tmp_path / 'x.db'}")
    with engine.begin() as conn:
        conn.execute(text("CREATE TABLE t (x INTEGER PRIMARY KEY)"))
        conn.execute(text("INSERT INTO t VALUES (1)"))

    def twice() -> None:
        with engine.begin() as conn:
            conn.execute(text("INSERT INTO t VALUES (1)"))

    exc = raised(twice)
    assert isinstance(exc, IntegrityError) and not ships_fault(exc)
    assert not ships_fault(ValueError("a header field out of range"))
    assert not ships_fault(OSError(errno.ENOENT, "no such file"))
    engine.dispose()
