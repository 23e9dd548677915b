"""A module's SD card fills up while it streams: the module stays up and says so, and takes frames
again once the card has room.

A real full file system: a small tmpfs mounted for the module's outbox (needs root; skipped
otherwise), filled by a file that takes all but ~0.5 MB of it.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import func, select

from ingest.service import IngestService
from storage import queries
from storage.models import Alarm, Frame
from tests.live.conftest import ingest_config
from tests.utils.live import make_agent, stop_and_drain, wait_for
from tests.utils.tmpfs import fill, small_tmpfs


@pytest.fixture
def card(tmp_path: Path) -> Iterator[Path]:
    with small_tmpfs(tmp_path / "card", 60) as where:
        yield where


@pytest.fixture
def service(tmp_path: Path) -> Iterator[IngestService]:
    """An ingest on SQLite: what is tested is the module's card (the live fixture's PostgreSQL
    variant would test nothing more)."""
    svc = IngestService(ingest_config(tmp_path / "data"))
    svc.start()
    yield svc
    svc.stop()


def test_a_full_card_keeps_the_module_up_alarms_and_capture_resumes_when_freed(
    service: IngestService, card: Path
) -> None:
    agent = make_agent("A", service.endpoint, card / "outbox")[0]
    agent.start()
    try:
        assert wait_for(lambda: agent.counters["acked"] >= 5, 30)
        filler = fill(card, leave_bytes=500_000)
        assert wait_for(lambda: agent.counters["card_skipped"] >= 3, 30), "the card never filled"
        captured = agent.counters["frames_captured"]
        # the module lives on: linked, heartbeats, its capture thread running; the ship says why
        assert not agent.stopped and not agent.capture_done()
        assert wait_for(lambda: service.health()["modules"]["A"]["card_skipped"] >= 3, 10)
        assert service.health()["modules"]["A"]["link"] == "up"

        def card_alarm() -> Alarm | None:
            with service.store.read() as s:
                return s.scalar(select(Alarm).where(Alarm.kind == "card", Alarm.active.is_(True)))

        assert wait_for(lambda: card_alarm() is not None, 10)
        assert "SD card" in card_alarm().message and card_alarm().severity == "MAJOR"
        filler.unlink()
        assert wait_for(lambda: agent.counters["frames_captured"] >= captured + 10, 30), "no capture after"
        assert stop_and_drain([agent], 60)
        with service.store.read() as s:
            stored = int(s.scalar(select(func.count(Frame.id))))
        assert stored == agent.counters["frames_captured"]
        # a frame the card could not keep was never numbered: the ship sees no gap
        assert service.store.call(queries.open_gaps, "A") == []
    finally:
        agent.stop()
