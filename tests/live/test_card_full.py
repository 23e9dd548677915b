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

from camcal.core.files import AppendLog
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


def test_acknowledgements_the_card_cannot_keep_do_not_stop_the_module(
    service: IngestService, tmp_path: Path
) -> None:
    """Found filling a card under a streaming module: the ship's acknowledgement of a frame sent
    before the card filled could not be written to `acked.log`, and its OSError ended the thread
    that sends, and with it the module (nothing more sent once the card had room again). Here the
    module's acknowledgement log is `/dev/full`, a real device on which every write fails with
    "No space left on device", so that every acknowledgement meets a full card."""
    agent = make_agent("A", service.endpoint, tmp_path / "outbox")[0]
    agent.outbox._acked_fh.close()
    agent.outbox._acked_fh = AppendLog(Path("/dev/full"), fsync=False)
    agent.start()
    try:
        assert wait_for(lambda: agent.counters["acked"] >= 20, 30), "the module stopped sending"
        assert not agent.stopped
        assert "an acknowledgement: No space left on device" in agent.device_errors.get("card", "")
        assert agent.counters["card_skipped"] == 0  # frames and sensor samples are kept as before
    finally:
        agent.stop()
