"""Schedule control end to end: API -> store -> ingest -> module over real sockets, exactly once."""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from camcal.core import wire
from camcal.core.schedule import presets
from server.app import create_app
from server.settings import ServerSettings
from storage.models import Event, Frame
from tests.live.conftest import ingest_config
from tests.live.test_ingest import wait_for
from tests.utils.live import TcpProxy, make_agent

TOKEN = "operator-token-1234"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def system(tmp_path: Path):
    from ingest.service import IngestService

    svc = IngestService(ingest_config(tmp_path / "data", command_retry_s=1.0))
    svc.start()
    proxy = TcpProxy(int(svc.endpoint.rsplit(":", 1)[1]))
    agent, camera = make_agent(
        "A", proxy.endpoint, tmp_path / "outbox", link_timeout_s=2.0, ack_timeout_s=5.0
    )
    agent.start()
    app = create_app(
        ServerSettings(data_dir=tmp_path / "data", events=None, operator_tokens={"ops": TOKEN}),
        store=svc.store,
    )
    with TestClient(app) as client:
        assert wait_for(lambda: agent.counters["acked"] >= 2, 20)
        yield svc, proxy, agent, camera, client
    agent.stop()
    proxy.close()
    svc.stop()


def command_state(client: TestClient, cid: str) -> str:
    return client.get(f"/api/commands/{cid}").json()["state"]


def test_send_a_schedule_see_frames_change_then_back_exactly_once(system) -> None:
    svc, _proxy, agent, camera, client = system
    scan = presets()["linearity-scan"].model_dump(mode="json")
    assert wait_for(lambda: svc.counters["frames_analysed"] >= 4, 20)
    preview = client.post("/api/schedules/preview", json={"schedule": scan, "module": "A"}).json()
    assert preview["ok"] and preview["n_frames"] == scan_frames(scan) and preview["pass_duration_s"] > 0
    assert preview["predictions"]["A"] and {"ok", "saturated"} & {
        p["verdict"] for p in preview["predictions"]["A"]
    }
    assert not [w for w in preview["warnings"] if "predicted usable" in w], preview["warnings"]
    # The longest exposure at the highest gain, nothing else: every setting saturates where frames
    # have been seen, and the preview says that wavelength would give no λ_att (sending stays allowed).
    blinding = {**scan, "exposures_s": [2.0], "gains_db": [24.0], "blocks": []}
    warned = client.post("/api/schedules/preview", json={"schedule": blinding, "module": "A"}).json()
    seen = {p["wavelength_nm"] for p in warned["predictions"]["A"] if p["verdict"] != "unknown"}
    unusable = [w for w in warned["warnings"] if "predicted usable for module A" in w]
    assert warned["ok"] and seen and len(unusable) == len(seen), warned["warnings"]
    assert all("1 saturated" in w and "no λ_att" in w for w in unusable), unusable
    r = client.post("/api/modules/A/schedule", json={"schedule": scan, "apply": "now"}, headers=AUTH)
    assert r.status_code == 202, r.text
    cmd = r.json()
    assert cmd["state"] == "pending" and cmd["target_version"] == 2 and cmd["issued_by"] == "ops"
    assert wait_for(lambda: command_state(client, cmd["id"]) == "done", 20)
    assert agent.runner.schedule.name == "linearity-scan" and agent.runner.schedule.version == 2
    n_before = len(camera.settings)
    assert wait_for(lambda: len(camera.settings) >= n_before + 4, 20)
    assert {e for e, _ in camera.settings[n_before:]} <= {0.01, 0.02, 0.03, 0.05, 0.07, 0.11, 0.15, 0.2, 0.3}
    assert wait_for(lambda: frames_with_version(svc, 2) >= 2, 20), "frames do not carry the new version"
    assert frame_events_with_version(svc, 2) >= 1, "the live frame events do not carry the schedule version"

    # The same command delivered again (a lost status): answered, not applied again.
    before = agent.counters["commands_repeated"]
    back = presets()["quick-check"].model_dump(mode="json")
    r = client.post(
        "/api/modules/A/schedule", json={"schedule": back, "apply": "end_of_setting"}, headers=AUTH
    )
    cmd2 = r.json()
    assert wait_for(lambda: command_state(client, cmd2["id"]) == "done", 30)
    assert agent.runner.schedule.name == "quick-check" and agent.runner.schedule.version == 3
    resend_to(svc, cmd2, back)
    assert wait_for(lambda: agent.counters["commands_repeated"] > before, 10)
    assert agent.runner.schedule.version == 3
    applied = [c for c in agent.outbox.read_jsonl("commands.jsonl") if c["command_id"] == cmd2["id"]]
    assert [c["state"] for c in applied].count("accepted") == 1

    audit = client.get("/api/audit").json()
    actions = [a["action"] for a in audit]
    assert actions.count("command.set_schedule") == 2 and "command.done" in actions
    csv = client.get("/api/audit/export")
    assert csv.status_code == 200 and "command.set_schedule" in csv.text


def test_a_command_to_an_offline_module_waits_pending_and_applies_once_after_reconnect(system) -> None:
    svc, proxy, agent, _camera, client = system
    proxy.cut()
    assert wait_for(lambda: client.get("/api/health").json() is not None and not agent.linked.is_set(), 10)
    assert wait_for(lambda: svc.health()["modules"]["A"]["link"] == "down", 10)
    r = client.post("/api/modules/A/commands", json={"action": "pause"}, headers=AUTH)
    assert r.status_code == 202
    cid = r.json()["id"]
    time.sleep(2.5)
    assert command_state(client, cid) == "pending"
    assert agent.runner.state == "running"
    proxy.restore()
    assert wait_for(lambda: command_state(client, cid) == "done", 30)
    assert agent.runner.state == "paused"
    r = client.post("/api/modules/A/commands", json={"action": "resume"}, headers=AUTH)
    assert wait_for(lambda: command_state(client, r.json()["id"]) == "done", 20)
    assert agent.runner.state == "running"
    states = [c["state"] for c in agent.outbox.read_jsonl("commands.jsonl") if c["command_id"] == cid]
    assert states.count("done") == 1


def test_commands_queued_while_offline_reach_the_module_in_the_order_they_were_issued(system) -> None:
    svc, proxy, agent, _camera, client = system
    proxy.cut()
    assert wait_for(lambda: svc.health()["modules"]["A"]["link"] == "down", 10)
    ids = []
    for action in ("pause", "resume"):
        r = client.post("/api/modules/A/commands", json={"action": action}, headers=AUTH)
        assert r.status_code == 202
        ids.append(r.json()["id"])
        time.sleep(0.05)  # distinct issue times
    proxy.restore()
    assert wait_for(lambda: all(command_state(client, c) == "done" for c in ids), 30)
    assert agent.runner.state == "running", "the resume issued last must be applied last"
    applied = [c["command_id"] for c in agent.outbox.read_jsonl("commands.jsonl") if c["state"] == "done"]
    assert applied.index(ids[0]) < applied.index(ids[1])


def test_bad_requests_get_clear_errors(system) -> None:
    _svc, _proxy, _agent, _camera, client = system
    good = presets()["quick-check"].model_dump(mode="json")
    r = client.post("/api/modules/A/schedule", json={"schedule": good})
    assert r.status_code == 401
    r = client.post(
        "/api/modules/A/schedule", json={"schedule": good}, headers={"Authorization": "Bearer nope-nope-1"}
    )
    assert r.status_code == 403
    r = client.post("/api/modules/Z/schedule", json={"schedule": good}, headers=AUTH)
    assert r.status_code == 404 and "Z" in r.json()["error"]["message"]
    for bad, field in (
        ({**good, "exposures_s": [5.0]}, "exposures_s"),
        ({**good, "gains_db": [2.05]}, "gains_db"),
        ({**good, "repeats": 0}, "repeats"),
        ({**good, "wavelengths_nm": [600]}, "wavelengths_nm"),
    ):
        r = client.post("/api/modules/A/schedule", json={"schedule": bad}, headers=AUTH)
        assert r.status_code == 422, r.text
        err = r.json()["error"]
        assert field in err["message"] and err["detail"][0]["reason"]
    r = client.post("/api/modules/A/schedule", json={"schedule": good, "version": 1}, headers=AUTH)
    assert r.status_code == 409 and "not newer" in r.json()["error"]["message"]


def scan_frames(s: dict) -> int:
    from camcal.core.schedule import Schedule

    return Schedule.model_validate(s).n_frames


def frames_with_version(svc, version: int) -> int:
    with svc.store.read() as s:
        return len(s.execute(select(Frame.id).where(Frame.schedule_version == version)).all())


def frame_events_with_version(svc, version: int) -> int:
    with svc.store.read() as s:
        payloads = s.scalars(select(Event.payload).where(Event.kind == "frame")).all()
    return sum(1 for p in payloads if p.get("schedule_version") == version)


def resend_to(svc, cmd: dict, schedule: dict) -> None:
    svc.send_to_module(
        "A",
        wire.Command(
            module="ship",
            command_id=cmd["id"],
            action="set_schedule",
            target_version=cmd["target_version"],
            schedule={**schedule, "version": cmd["target_version"]},
        ),
    )
