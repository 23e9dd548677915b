"""Fixtures for the live path: a real ingest service on 127.0.0.1, on SQLite and on PostgreSQL."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from ingest.alarms import AlarmLimits
from ingest.service import IngestConfig, IngestService


def ingest_config(data: Path, **over) -> IngestConfig:
    base = dict(
        data_dir=data,
        bind="tcp://127.0.0.1:*",
        events_bind="tcp://127.0.0.1:*",
        workers=1,
        sqlite_synchronous="NORMAL",
        link_timeout_s=2.0,
        alarm_limits=AlarmLimits(link_timeout_s=2.0),
        plaintext=True,  # in-process tests of the ingest's logic; the link's keys have their own tests
    )
    base.update(over)
    return IngestConfig(**base)


@pytest.fixture
def service(tmp_path: Path, db_url: str | None) -> Iterator[IngestService]:
    """An ingest on SQLite (in its data folder) or on a fresh PostgreSQL database (``db_url``)."""
    svc = IngestService(ingest_config(tmp_path / "data", db_url=db_url))
    svc.start()
    yield svc
    svc.stop()
