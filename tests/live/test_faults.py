"""The ingest killed with SIGKILL again and again while two modules stream: nothing lost, nothing doubled."""

from __future__ import annotations

import hashlib
import os
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest
from sqlalchemy import func, select

from camcal.core.frameset import read_manifest
from storage.models import Event, Frame, FrameResult, IngestCounter
from storage.store import Store
from tests.live.test_ingest import wait_for
from tests.utils.live import make_agent, start_ingest, stop_and_drain


def free_port() -> int:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


@pytest.mark.slow
def test_sigkill_the_ingest_repeatedly_and_every_frame_is_stored_exactly_once(tmp_path: Path) -> None:
    data = tmp_path / "data"
    port, events_port = free_port(), free_port()
    proc = start_ingest(data, port, events_port)
    agents = [
        make_agent(
            m,
            f"tcp://127.0.0.1:{port}",
            tmp_path / f"outbox-{m}",
            keys_dir=data / "keys",  # made by start_ingest
            link_timeout_s=2.0,
            ack_timeout_s=4.0,
        )[0]
        for m in ("A", "B")
    ]
    for a in agents:
        a.start()
    kills = 0
    try:
        for _ in range(3):
            target = min(a.counters["acked"] for a in agents) + 4
            assert wait_for(lambda t=target: all(a.counters["acked"] >= t for a in agents), 60)
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
            kills += 1
            time.sleep(1.0)
            proc = start_ingest(data, port, events_port)
        assert wait_for(lambda: all(a.counters["frames_captured"] >= 30 for a in agents), 60)
        assert stop_and_drain(agents), [a.outbox.pending_count() for a in agents]
        store = Store.open(data, run_migrations=False)
        with store.read() as s:
            n_frames = s.scalar(select(func.count(Frame.id)))
        assert wait_for(lambda: _results(store) == n_frames, 60), "frames left unanalysed after the restarts"
        # The counters were kept with the data they count: none fell behind through the kills.
        with store.read() as s:
            counted = {n: v for n, v in s.execute(select(IngestCounter.name, IngestCounter.value))}
        assert counted.get("counters.frames_stored") == n_frames, (counted, n_frames)
    finally:
        for a in agents:
            a.stop()
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    assert kills == 3
    for a in agents:
        sent = {(r.boot, r.seq): r for r in read_manifest(a.config.outbox / "frames")}
        with store.read() as s:
            rows = list(s.scalars(select(Frame).where(Frame.module_id == a.config.module)))
        keys = [(r.boot, r.seq) for r in rows]
        assert len(keys) == len(set(keys)) == len(sent), "a frame is missing or stored twice"
        assert set(keys) == set(sent)
        for r in rows:
            stored = store.files.resolve(r.path).read_bytes()
            original = (a.config.outbox / "frames" / sent[(r.boot, r.seq)].file).read_bytes()
            assert hashlib.sha256(stored).hexdigest() == r.sha256 == hashlib.sha256(original).hexdigest()
    with store.read() as s:  # written in the frame's own transaction: no SIGKILL can part them
        framed = {int(e.payload["frame_id"]) for e in s.scalars(select(Event).where(Event.kind == "frame"))}
        all_ids = set(s.scalars(select(Frame.id)))
    assert all_ids <= framed, f"{len(all_ids - framed)} stored frames have no frame event"
    assert store.integrity_check() == "ok"
    store.close()


def _results(store: Store) -> int:
    with store.read() as s:
        return int(s.scalar(select(func.count(FrameResult.id))))
