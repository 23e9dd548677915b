"""A module on a real GenICam camera: the GigE Vision emulator, a real agent, a real ingest and the
control API, over real sockets. Nothing stands in: the camera speaks GVCP/GVSP over UDP.

* the camera's ranges reach the ship and check schedules there; a schedule sent from the control
  page's API reaches the camera's registers, and the frames record what the camera applied;
* 8- and 16-bit frames are stored and analysed on the same gray scale;
* the camera pulled (the emulator killed amid the captures) and plugged back: the module goes on,
  the ship raises the camera alarm and clears it, and no frame is lost or stored twice.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import select

from camcal.core.images import read_frame_scaled
from camcal.core.schedule import Schedule
from ingest.alarms import AlarmLimits
from ingest.service import IngestService
from lrm.agent import Agent, AgentConfig
from lrm.runner import ScheduleRunner
from server.app import create_app
from server.settings import ServerSettings
from storage.models import Alarm, Frame, FrameResult
from tests.live.conftest import ingest_config
from tests.utils.aravis import FakeGigECamera
from tests.utils.live import RealClock, stop_and_drain, wait_for

TOKEN = "operator-token-aravis"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def schedule(version: int = 1, exposures_s: tuple[float, ...] = (0.01,)) -> Schedule:
    return Schedule(
        name="bench",
        version=version,
        exposures_s=exposures_s,
        gains_db=(2.0, 4.0),
        repeats=2,
        wavelengths_nm=(460,),
        pause_s=0.2,
    )


def aravis_agent(gige: FakeGigECamera, endpoint: str, outbox: Path, module: str = "A", **camera) -> Agent:
    from lrm.cameras.aravis import AravisCamera

    cam = AravisCamera(gige.serial, module, width_px=160, height_px=120, frame_timeout_s=1.0, **camera)
    runner = ScheduleRunner(cam, RealClock(), schedule())
    cfg = AgentConfig(module=module, connect=endpoint, outbox=outbox, fsync=False, plaintext=True)
    return Agent(cfg, clock=RealClock(), runner=runner, camera_limits=cam.limits, camera_info=cam.info)


def stored(svc: IngestService, module: str = "A") -> list[tuple[Frame, FrameResult | None]]:
    with svc.store.read() as s:
        rows = s.execute(
            select(Frame, FrameResult)
            .outerjoin(FrameResult, FrameResult.frame_id == Frame.id)
            .where(Frame.module_id == module)
            .order_by(Frame.seq)
        ).all()
        return [(f, r) for f, r in rows]


@pytest.fixture
def gige():
    with FakeGigECamera() as cam:
        yield cam


def test_the_camera_s_ranges_check_schedules_and_a_sent_schedule_reaches_its_registers(
    gige: FakeGigECamera, tmp_path: Path
) -> None:
    svc = IngestService(ingest_config(tmp_path / "data", command_retry_s=1.0))
    svc.start()
    agent = aravis_agent(gige, svc.endpoint, tmp_path / "outbox")
    cam = agent.runner.camera
    agent.start()
    app = create_app(
        ServerSettings(data_dir=tmp_path / "data", events=None, operator_tokens={"ops": TOKEN}),
        store=svc.store,
    )
    try:
        with TestClient(app) as client:
            assert wait_for(lambda: svc.counters["frames_analysed"] >= 4, 30), svc.counters
            said = {m["id"]: m for m in client.get("/api/modules").json()}["A"]["camera"]
            assert said["model"] == "Aravis Fake" and said["serial"] == gige.serial
            assert said["exposure_range_s"] == [1e-5, 10.0] and said["gain_step_db"] == 1.0

            # 5 s exceeds the ship's default limits (2 s) but not this camera's (10 s); 0.5 dB is
            # no step of its gain (1 dB), 20 s none of its exposures
            long = schedule(exposures_s=(5.0,)).model_dump(mode="json")
            p = client.post("/api/schedules/preview", json={"schedule": long, "camera_of": "A"}).json()
            assert p["ok"], p["problems"]
            assert p["camera_limits"]["source"] == f"module A's camera (Aravis Fake {gige.serial})"
            assert not client.post("/api/schedules/preview", json={"schedule": long}).json()["ok"]
            bad = {**long, "exposures_s": [20.0], "gains_db": [0.5]}
            p = client.post("/api/schedules/preview", json={"schedule": bad, "camera_of": "A"}).json()
            reasons = " ".join(x["reason"] for x in p["problems"])
            assert "exposure 20.0 s outside the camera's range [1e-05, 10.0] s" in reasons
            assert "not a multiple of the 1.0 dB step" in reasons
            r = client.post("/api/modules/A/schedule", json={"schedule": bad}, headers=AUTH)
            assert r.status_code == 422 and "checked against module A's camera" in r.text, r.text

            new = {**long, "exposures_s": [0.0345], "gains_db": [5.0], "pause_s": 0.0}
            r = client.post("/api/modules/A/schedule", json={"schedule": new}, headers=AUTH)
            assert r.status_code == 202, r.text
            cid = r.json()["id"]
            assert wait_for(lambda: client.get(f"/api/commands/{cid}").json()["state"] == "done", 30)
            assert wait_for(lambda: cam.read_settings() == (0.0345, 5.0), 10), cam.read_settings()
            assert wait_for(lambda: sum(f.schedule_version == 2 for f, _ in stored(svc)) >= 2, 20)
        frames = stored(svc)
        assert {(f.exposure_s, f.gain_db) for f, _ in frames if f.schedule_version == 2} == {(0.0345, 5.0)}
        assert {(f.exposure_s, f.gain_db) for f, _ in frames if f.schedule_version == 1} <= {
            (0.01, 2.0),
            (0.01, 4.0),
        }
        analysed = [r for _, r in frames if r is not None]
        assert analysed and all(r.reason != "bad_format" for r in analysed)
    finally:
        agent.stop()
        cam.close()
        svc.stop()


def _background(detail: str | None) -> float:
    """The frame's background level the analysis names ("... over a background of 127.2 ± 73.6")."""
    assert detail and "background of " in detail, detail
    return float(detail.split("background of ")[1].split()[0])


def test_8_and_16_bit_frames_are_stored_as_they_came_and_analysed_on_one_gray_scale(
    gige: FakeGigECamera, tmp_path: Path
) -> None:
    svc = IngestService(ingest_config(tmp_path / "data"))
    svc.start()
    try:
        backgrounds = {}
        for module, fmt in (("A", "Mono8"), ("B", "Mono16")):
            agent = aravis_agent(gige, svc.endpoint, tmp_path / f"outbox-{module}", module, pixel_format=fmt)
            agent.start()
            try:
                assert wait_for(lambda m=module: sum(r is not None for _, r in stored(svc, m)) >= 3, 30)
            finally:
                agent.stop()
                agent.runner.camera.close()
            frames = stored(svc, module)
            image, top = read_frame_scaled(svc.store.files.root / frames[0][0].path)
            assert image.dtype == (np.uint8 if fmt == "Mono8" else np.uint16)
            assert top == (255 if fmt == "Mono8" else 65535) and image.max() > (0 if fmt == "Mono8" else 255)
            results = [r for f, r in frames if r is not None and f.exposure_s == 0.01 and f.gain_db == 2.0]
            assert results and not any(r.reason in ("bad_format", "unreadable") for r in results)
            # the emulator's ramp holds no LEM: the analysis says so and names the background it saw
            said = [_background(r.detail) for r in results if r.reason == "no_source"]
            assert said, [(r.reason, r.detail) for r in results]
            backgrounds[fmt] = np.median(said)
        # the same light on the same 8-bit gray scale, whatever the depth (not 256 times more; the
        # emulator's ramp moves with each frame, a few gray)
        assert backgrounds["Mono16"] == pytest.approx(backgrounds["Mono8"], rel=0.08), backgrounds
    finally:
        svc.stop()


def _outbox_seqs(outbox: Path) -> list[int]:
    with (outbox / "frames" / "manifest.csv").open() as fh:
        return [int(row["seq"]) for row in csv.DictReader(fh)]


def test_a_camera_pulled_and_plugged_back_is_alarmed_cleared_and_loses_no_frame(
    gige: FakeGigECamera, tmp_path: Path
) -> None:
    # the camera alarm holds 6 s after the last failure here (2 min on a ship): longer than the
    # module's waits between tries while the camera is away in this test (1-2 s, and a second each
    # to look for the camera), so that it holds until the camera is back
    hold = AlarmLimits(link_timeout_s=2.0, card_hold_s=6.0)
    svc = IngestService(ingest_config(tmp_path / "data", alarm_limits=hold))
    svc.start()
    agent = aravis_agent(gige, svc.endpoint, tmp_path / "outbox")
    agent.start()

    def camera_alarm() -> Alarm | None:
        with svc.store.read() as s:
            return s.scalars(select(Alarm).where(Alarm.module_id == "A", Alarm.kind == "camera")).first()

    try:
        assert wait_for(lambda: agent.counters["acked"] >= 6, 30), agent.counters
        gige.kill()  # amid the captures: one may be on the wire
        pulled_at = agent.counters["frames_captured"]
        assert wait_for(lambda: (a := camera_alarm()) is not None and a.active, 40), agent.counters
        assert "stopped answering" in (agent.device_errors.get("camera") or ""), agent.device_errors
        assert not agent.stopped and agent.counters["frames_captured"] <= pulled_at + 1
        gige.start()  # plugged back: the same camera
        assert wait_for(lambda: agent.counters["frames_captured"] >= pulled_at + 6, 40), agent.counters
        assert agent.runner.camera.counters["reopened"] == 1
        assert wait_for(lambda: not camera_alarm().active, 30), camera_alarm().message
        assert "camera failed" in camera_alarm().message
        assert stop_and_drain([agent], timeout=30)
        on_card = _outbox_seqs(tmp_path / "outbox")
        assert on_card == list(range(1, len(on_card) + 1)), "a sequence number skipped or taken twice"
        on_ship = [f.seq for f, _ in stored(svc)]
        assert on_ship == on_card, "the ship lost a frame or stored one twice"
    finally:
        agent.stop()
        agent.runner.camera.close()
        svc.stop()
