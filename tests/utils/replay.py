"""A stored dive made by the live path: a frame set's two cameras replayed into a real ingest."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from sqlalchemy import func, select

from camcal.core.frameset import read_setup
from ingest.alarms import AlarmLimits
from ingest.service import IngestConfig, IngestService
from lrm.agent import Agent, AgentConfig
from lrm.replay import ReplaySource
from storage.models import Frame, FrameResult
from tests.utils.live import RealClock


def stream_frame_set(
    folder: Path, data: Path, *, db_url: str | None = None, dive: str = "replayed", timeout_s: float = 120.0
) -> dict[str, Any]:
    """Replay cameras A and B of ``folder`` as fast as the link takes them into an ingest on ``data``.

    Returns when every frame is stored and analysed in the dive's live run
    (with the frame set's setup.json as its calibration).
    """
    svc = IngestService(
        IngestConfig(
            data_dir=data,
            db_url=db_url,
            bind="tcp://127.0.0.1:*",
            events_bind=None,
            workers=1,
            fsync=False,
            sqlite_synchronous="NORMAL",
            dive_name=dive,
            setup=read_setup(folder),
            alarm_limits=AlarmLimits(link_timeout_s=5.0),
            plaintext=True,
        )
    )
    svc.start()
    clock = RealClock()
    agents = [
        Agent(
            AgentConfig(
                m, svc.endpoint, data.parent / f"replay-{m}", fsync=False, initial_window=8, plaintext=True
            ),
            clock=clock,
            source=ReplaySource(folder, m, clock, speed=0),
        )
        for m in ("A", "B")
    ]
    try:
        for a in agents:
            a.start()
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not all(
            a.capture_done() and a.outbox.pending_count() == 0 for a in agents
        ):
            time.sleep(0.05)
        with svc.store.read() as s:
            n = int(s.scalar(select(func.count(Frame.id))))
        while time.monotonic() < end:
            with svc.store.read() as s:
                if int(s.scalar(select(func.count(FrameResult.id)))) >= n:
                    break
            time.sleep(0.05)
        time.sleep(1.2)  # one more tick of the store thread: linearity
    finally:
        for a in agents:
            a.stop()
        svc.stop()
    return {"dive_id": svc.dive.id, "run_id": svc.run.id, "frames": n}
