"""A burst of operator commands, and a running module that sends no frame: a real ingest, a module
streaming to it over ZeroMQ, and the server's control API on the same store.

Seen on deck: after an API fuzzer with the operator token (5 min), both modules read ``running`` but
stored no frame for ~5 minutes, and nothing said so. Reproduced against a real `camcal up`: an
explicit schedule version of 2**31-1 made the next one 2**31, which the ingest could not put on the
wire: every round of deliveries failed on it, and every later command (the operator's ``start``)
waited behind it for ever; thousands of queued commands were sent newest-first-of-the-last-200, so
a queued ``pause`` arrived after the operator's ``start``, and the store thread spent minutes
delivering them while the modules restarted their schedules at each.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from ingest.alarms import AlarmLimits
from ingest.service import IngestService
from server.app import create_app
from server.routers.control import UNANSWERED_MAX
from server.settings import ServerSettings
from storage.models import Alarm, Frame
from tests.live.conftest import ingest_config
from tests.utils.live import make_agent, wait_for

TOKEN = "operator-token-5678"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def frames(svc: IngestService) -> int:
    with svc.store.read() as s:
        return int(s.scalar(select(func.count(Frame.id))) or 0)


def active(svc: IngestService, kind: str) -> list[Alarm]:
    with svc.store.read() as s:
        return list(s.scalars(select(Alarm).where(Alarm.kind == kind, Alarm.active.is_(True))))


@pytest.fixture
def ship(tmp_path: Path):
    svc = IngestService(ingest_config(tmp_path / "data", command_retry_s=1.0))
    svc.start()
    agent, camera = make_agent("A", svc.endpoint, tmp_path / "outbox", link_timeout_s=2.0)
    agent.start()
    app = create_app(
        ServerSettings(data_dir=tmp_path / "data", events=None, operator_tokens={"ops": TOKEN}),
        store=svc.store,
    )
    with TestClient(app) as client:
        assert wait_for(lambda: frames(svc) >= 2, 30)
        yield svc, agent, camera, client
    agent.stop()
    svc.stop()


def test_a_burst_of_commands_ends_with_the_module_running_the_last_one_and_taking_frames(
    ship, tmp_path: Path
) -> None:
    svc, agent, _camera, client = ship
    quick = {"exposures_s": [0.05], "gains_db": [6.0], "repeats": 2, "wavelengths_nm": [460]}
    # The largest version leaves no newer one: refused, as is a jump past what the module runs.
    for version in (2**31 - 1, 5000):
        r = client.post("/api/modules/A/schedule", json={"schedule": quick, "version": version}, headers=AUTH)
        assert r.status_code == 409 and "leave the version out" in r.json()["error"]["message"], r.text
    # A burst while the module is away (a module that answers keeps up with a test client, or not,
    # as the machine goes): pauses and resumes, stops and schedules, as fast as the API takes them.
    agent.stop()
    codes = []
    for i in range(3 * UNANSWERED_MAX):
        if i % 4 == 3:
            r = client.post("/api/modules/A/schedule", json={"schedule": quick}, headers=AUTH)
        else:
            r = client.post(
                "/api/modules/A/commands", json={"action": ("pause", "stop", "resume")[i % 3]}, headers=AUTH
            )
        codes.append(r.status_code)
    assert codes == [202] * UNANSWERED_MAX + [409] * (2 * UNANSWERED_MAX), codes
    # The module back (a new boot on the same card): the queue is delivered, oldest first.
    agent, _ = make_agent("A", svc.endpoint, tmp_path / "outbox", link_timeout_s=2.0)
    agent.start()
    try:
        _the_last_word_runs(svc, agent, client)
    finally:
        agent.stop()


def _the_last_word_runs(svc: IngestService, agent: Any, client: TestClient) -> None:
    # Once the module has answered them, the operator's last word is a pause, then a start.
    assert wait_for(
        lambda: (
            client.post("/api/modules/A/commands", json={"action": "pause"}, headers=AUTH).status_code == 202
        ),
        60,
        interval=0.5,
    )
    start = client.post("/api/modules/A/commands", json={"action": "start"}, headers=AUTH)
    assert start.status_code == 202, start.text
    assert wait_for(lambda: client.get(f"/api/commands/{start.json()['id']}").json()["state"] == "done", 30)
    assert wait_for(lambda: agent.runner.state == "running", 10), agent.runner.state
    n = frames(svc)
    assert wait_for(lambda: frames(svc) >= n + 3, 30), "the module runs but stores no frame"
    waiting = client.get("/api/commands", params={"state": "pending"}).json()
    assert waiting == [], waiting


class HangingCamera:
    """The module's camera, hanging in a capture while ``hang`` is set (a USB camera that stopped)."""

    def __init__(self, camera: Any) -> None:
        self.camera = camera
        self.hang = threading.Event()

    def capture(self, exposure_s: float, gain_db: float) -> Any:
        while self.hang.is_set():
            time.sleep(0.05)
        return self.camera.capture(exposure_s, gain_db)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.camera, name)


def test_a_running_module_that_sends_no_frame_raises_an_alarm_that_says_why(tmp_path: Path) -> None:
    svc = IngestService(
        ingest_config(tmp_path / "data", alarm_limits=AlarmLimits(link_timeout_s=2.0, no_frame_grace_s=2.0))
    )
    svc.start()
    agent, camera = make_agent("A", svc.endpoint, tmp_path / "outbox", link_timeout_s=2.0)
    hanging = HangingCamera(camera)
    assert agent.runner is not None
    agent.runner.camera = hanging
    agent.start()
    try:
        assert wait_for(lambda: frames(svc) >= 2, 30)
        assert not active(svc, "no_frames")
        hanging.hang.set()
        assert wait_for(lambda: active(svc, "no_frames"), 30), "a running module sends nothing, unsaid"
        (alarm,) = active(svc, "no_frames")
        assert alarm.severity == "MAJOR" and alarm.module_id == "A"
        assert "runs schedule quick (version 1) but has sent no frame since" in alarm.message
        assert "its camera or its schedule runner hangs" in alarm.message, alarm.message
        assert agent.runner.state == "running"
        hanging.hang.clear()
        assert wait_for(lambda: not active(svc, "no_frames"), 30), "the alarm outlived the frames' return"
        # Paused by the operator: no frame is due, no alarm.
        agent.runner.pause()
        time.sleep(4.0)  # twice the grace
        assert not active(svc, "no_frames")
    finally:
        hanging.hang.clear()
        agent.stop()
        svc.stop()
