"""Modules stream into the ingest over real TCP: everything stored once, analysed, and faults survived."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from typing import Any

import pytest
import zmq
from sqlalchemy import func, select

from camcal.core import wire
from ingest.service import IngestService
from ingest.worker import analyse_stored_frame
from storage.models import Alarm, AttenuationPoint, Event, Frame, FrameResult, SensorSample
from tests.live.conftest import ingest_config
from tests.utils.live import TcpProxy, make_agent, stop_and_drain, wait_for


def stored_keys(svc: IngestService, module: str) -> list[tuple[str, int]]:
    with svc.store.read() as s:
        return [(b, q) for b, q in s.execute(select(Frame.boot, Frame.seq).where(Frame.module_id == module))]


def count(svc: IngestService, model) -> int:
    with svc.store.read() as s:
        return int(s.scalar(select(func.count(model.id))))


def test_two_modules_every_frame_stored_once_analysed_with_attenuation(
    service: IngestService, tmp_path: Path
) -> None:
    # the analysis processes start with the ingest, before any frame (their imports take a second)
    assert wait_for(service.analysis_ready.is_set, 60)
    assert service.health()["analysis_ready"] is True
    agents = [make_agent(m, service.endpoint, tmp_path / f"outbox-{m}")[0] for m in ("A", "B")]
    for a in agents:
        a.start()
    assert wait_for(lambda: all(a.counters["frames_captured"] >= 12 for a in agents), 30)
    assert stop_and_drain(agents, 20)
    for a in agents:
        keys = stored_keys(service, a.config.module)
        assert len(keys) == len(set(keys)) == a.counters["frames_captured"]
    n_frames = count(service, Frame)
    assert wait_for(lambda: count(service, FrameResult) == n_frames, 30)
    assert count(service, SensorSample) > 10
    with service.store.read() as s:
        points = list(s.scalars(select(AttenuationPoint).where(AttenuationPoint.wavelength_nm == 460)))
        kinds = {k for (k,) in s.execute(select(Event.kind).distinct())}
    assert points, "no λ_att point"
    truth = 1 / (1 / 65 + 1 / 50)
    assert points[-1].lambda_att_m == pytest.approx(truth, rel=0.05)
    assert points[-1].stat_err_m > 0 and points[-1].sys_err_m > 0
    assert {"frame", "result", "attenuation", "link"} <= kinds
    health = service.health()
    assert health["modules"]["A"]["link"] == "up" and health["counters"]["frames_stored"] == n_frames
    for a in agents:
        a.stop()


def test_malformed_messages_are_counted_dropped_and_the_good_stream_goes_on(
    service: IngestService, tmp_path: Path
) -> None:
    agent, _ = make_agent("A", service.endpoint, tmp_path / "outbox")
    agent.start()
    ctx = zmq.Context.instance()
    rogue = ctx.socket(zmq.DEALER)
    rogue.connect(service.endpoint)
    good = wire.encode(wire.Hello(module="R", boot="x"))
    bad = [
        [b"not json at all"],
        [json.dumps({"v": 9, "type": "hello", "module": "R", "boot": "x"}).encode()],
        [json.dumps({"v": 1, "type": "frame", "module": "R"}).encode(), b"payload"],
        [bytes(good[0]), b"unexpected payload"],
        [b"{" * (wire.MAX_HEADER_BYTES + 10)],
        [b"\x00\xff" * 50, b"\x01", b"\x02"],
    ]
    for _ in range(3):
        for parts in bad:
            rogue.send_multipart(parts)
    assert wait_for(lambda: sum(service.malformed.values()) >= 3 * len(bad), 10)
    assert set(service.malformed) == {
        "bad_header",
        "bad_version",
        "invalid_field",
        "bad_framing",
        "oversized",
    }
    assert wait_for(lambda: agent.counters["frames_captured"] >= 6, 20)
    assert stop_and_drain([agent], 20)
    assert len(stored_keys(service, "A")) == agent.counters["frames_captured"]
    rogue.close(0)
    agent.stop()


def test_a_cut_link_buffers_in_the_outbox_and_catches_up(service: IngestService, tmp_path: Path) -> None:
    port = int(service.endpoint.rsplit(":", 1)[1])
    proxy = TcpProxy(port)
    agent, _ = make_agent("A", proxy.endpoint, tmp_path / "outbox", link_timeout_s=2.0, ack_timeout_s=5.0)
    agent.start()
    assert wait_for(lambda: agent.counters["acked"] >= 4, 20)
    proxy.cut()
    assert wait_for(lambda: not agent.linked.is_set(), 10), "the agent did not notice the cut"
    assert wait_for(lambda: agent.outbox.pending_count() >= 5, 20), "nothing buffered during the cut"
    assert wait_for(lambda: service.health()["modules"]["A"]["link"] == "down", 10)
    buffered = agent.outbox.pending_count()
    proxy.restore()
    assert wait_for(lambda: agent.linked.is_set(), 15)
    assert stop_and_drain([agent], 30), f"{agent.outbox.pending_count()} of {buffered} still pending"
    keys = stored_keys(service, "A")
    assert len(keys) == len(set(keys)) == agent.counters["frames_captured"]
    assert agent.counters["link_lost"] >= 1 and agent.counters["resends_queued"] >= 0
    with service.store.read() as s:
        states = [e.payload["state"] for e in s.scalars(select(Event).where(Event.kind == "link"))]
    assert states[:3] == ["up", "down", "up"]
    agent.stop()
    proxy.close()


def test_a_killed_analysis_process_is_replaced_and_every_frame_still_analysed(
    service: IngestService, tmp_path: Path
) -> None:
    """SIGKILL (the OOM killer's signal) to the analysis process while a module streams: Python's
    pool is broken by it; the ingest starts a new one, analyses every frame, and raises an alarm."""
    assert wait_for(service.analysis_ready.is_set, 60)
    agent = make_agent("A", service.endpoint, tmp_path / "outbox")[0]
    agent.start()
    assert wait_for(lambda: count(service, FrameResult) >= 5, 30)
    for pid in list(service.analysis.pool._processes):
        os.kill(pid, signal.SIGKILL)
    analysed = count(service, FrameResult)
    assert wait_for(lambda: count(service, FrameResult) >= analysed + 10, 60), "no result after the kill"
    assert stop_and_drain([agent], 20)
    n_frames = count(service, Frame)
    assert wait_for(lambda: count(service, FrameResult) == n_frames, 60)
    with service.store.read() as s:
        statuses = set(s.scalars(select(FrameResult.status)))
        alarms = list(s.scalars(select(Alarm).where(Alarm.kind == "analysis_crash")))
    assert statuses == {"ok"}  # the frames of the killed pool were analysed again, not rejected
    assert service.health()["counters"]["analysis_restarts"] == 1
    assert len(alarms) == 1 and alarms[0].severity == "MINOR" and "replaced" in alarms[0].message
    assert service.analysis_ready.is_set()
    agent.stop()


def analyse_with_an_unstorable_value(path: str, config: Any, thumb: str | None) -> dict[str, Any]:
    """In the analysis process: the real analysis, but every third frame's result carries a value the
    database has no column for (as a worker of another version would send): refused for its own sake."""
    row = analyse_stored_frame(path, config, thumb)
    if int(Path(path).stem) % 3 == 0:
        row["no_such_column"] = 1.0
    return row


def test_a_result_the_database_refuses_costs_only_itself_and_is_counted_once(
    tmp_path: Path, db_url: str | None
) -> None:
    """Results are stored in batches; a batch with a result the database refuses is stored result
    by result: the good ones as they are, the refused one as a rejected result of its frame (so the
    frame is not left unanalysed), and every result taken in (counted, alarms, λ_att) once."""
    svc = IngestService(ingest_config(tmp_path / "data", db_url=db_url))
    svc.analysis._analyse = analyse_with_an_unstorable_value  # the one stand-in: a worker's bad value
    svc.start()
    try:
        assert wait_for(svc.analysis_ready.is_set, 60)
        agent = make_agent("A", svc.endpoint, tmp_path / "outbox")[0]
        agent.start()
        assert wait_for(lambda: agent.counters["frames_captured"] >= 15, 30)
        assert stop_and_drain([agent], 20)
        n_frames = count(svc, Frame)
        assert wait_for(lambda: count(svc, FrameResult) == n_frames, 30), "a frame was left without result"
        with svc.store.read() as s:
            outcome = {
                seq: (status, reason, detail)
                for seq, status, reason, detail in s.execute(
                    select(Frame.seq, FrameResult.status, FrameResult.reason, FrameResult.detail).join(
                        FrameResult, FrameResult.frame_id == Frame.id
                    )
                )
            }
            result_events = [e.payload for e in s.scalars(select(Event).where(Event.kind == "result"))]
        refused = {q for q, (_, reason, detail) in outcome.items() if reason == "analysis_error"}
        assert refused == {q for q in outcome if q % 3 == 0} and refused
        assert all("could not be stored" in (outcome[q][2] or "") for q in refused)
        assert all(outcome[q][0] == "ok" for q in outcome if q not in refused)
        assert sorted(e["seq"] for e in result_events) == sorted(outcome)  # one event each
        assert {e["seq"] for e in result_events if e["status"] == "rejected"} == refused
        assert svc.health()["counters"]["frames_analysed"] == n_frames  # each result taken in once
        agent.stop()
    finally:
        svc.stop()
