"""The ship's data disk fills up while a module streams, then space is freed: nothing is refused for
good, and every frame the module took is stored and analysed once the disk has room again.

A real full file system: a small tmpfs mounted for the test (needs root; skipped otherwise), the
ingest's data folder on it, and a file that takes all but ~1 MB of it.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import func, select

from analysis import FrameConfig
from camcal.core.images import encode_png
from ingest.service import IngestService
from ingest.worker import analyse_stored_frame
from storage.models import Frame, FrameResult
from tests.live.conftest import ingest_config
from tests.utils.live import make_agent, stop_and_drain, wait_for
from tests.utils.sim import SMALL_CAMERA, renderer
from tests.utils.tmpfs import fill, small_tmpfs


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    with small_tmpfs(tmp_path / "disk", 200) as where:
        yield where


def count(svc: IngestService, model: type) -> int:
    with svc.store.read() as s:
        return int(s.scalar(select(func.count(model.id))) or 0)  # type: ignore[attr-defined]


def test_a_full_disk_refuses_nothing_for_good_and_every_frame_arrives_once_freed(
    small_disk: Path, tmp_path: Path
) -> None:
    svc = IngestService(ingest_config(small_disk / "data", workers=1))
    svc.start()
    resends = 2  # a module that gives up sooner than the default, so that the outage can be short
    agent = make_agent("A", svc.endpoint, tmp_path / "outbox", max_resends=resends)[0]
    try:
        agent.start()
        assert wait_for(lambda: count(svc, FrameResult) >= 5, 30)
        # all but ~1 MB (written, not sparse): a few frames more fit, then nothing
        filler = fill(small_disk, leave_bytes=1_000_000)
        # Longer than the module's limited resends (1 + 2 + 4 s for three tries): a message refused
        # for a reason that is the ship's own must be resent until it works.
        time.sleep(sum(2.0**k for k in range(resends + 1)) + 4.0)
        assert agent.counters["nacked_internal_error"] > 0, "the disk never filled"
        assert agent.outbox.pending_count() > 20
        assert agent.counters["refused"] == 0
        filler.unlink()
        assert stop_and_drain([agent], 90), f"{agent.outbox.pending_count()} still pending"
        stored = count(svc, Frame)
        assert stored == agent.counters["frames_captured"]
        assert wait_for(lambda: count(svc, FrameResult) == stored, 60)
        with svc.store.read() as s:
            assert set(s.scalars(select(FrameResult.status))) == {"ok"}
        assert svc.health()["counters"].get("quarantined", 0) == 0
        assert agent.counters["refused"] == 0 and not list((small_disk / "data").glob("quarantine/*"))
    finally:
        agent.stop()
        svc.stop()


def test_a_thumbnail_the_full_disk_cannot_take_costs_the_thumbnail_not_the_result(tmp_path: Path) -> None:
    """Found by this file's first test in CI: a frame analysed just as the disk filled was stored as
    rejected for good ("No space left on device" writing its thumbnail), though its analysis had
    worked. Now the result is kept, and the dashboard makes the thumbnail when asked."""
    render = renderer("trex", 21.56, camera=SMALL_CAMERA, camera_id="A")
    pixels, _ = render.render(460, 0.05, 8.0, rng=np.random.default_rng(1))
    frame = tmp_path / "frame.png"
    frame.write_bytes(encode_png(pixels))
    with small_tmpfs(tmp_path / "disk", 1) as disk:
        fill(disk)  # full: not a byte left
        thumb = disk / "thumbs" / "1.jpg"
        row = analyse_stored_frame(str(frame), FrameConfig(), str(thumb))
        assert row["status"] == "ok" and row["i_center_gray"] > 0
        assert not thumb.exists()
