"""A module whose camera or sensors fail now and then (a loose cable, a bus glitch): it goes on.

Before, one failed capture or sensor read ended the agent thread that met it and with it the
whole module (it signed off: no frames, no heartbeats, no commands for the rest of the dive).
Now each failure is counted, said in the heartbeat and tried again; the ship raises an alarm
that says what to check. The camera and the sensors are the stand-ins here (they fail on cue);
the module agent, the link and the ingest are real.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from sqlalchemy import select

from ingest.service import IngestService
from lrm.camera import CaptureFailed
from storage.models import Alarm
from tests.utils.live import make_agent, wait_for

CAMERA_FAILS = (3, 5, 7)  # the captures that fail (not in a row: each costs a 1 s wait)
SENSOR_FAILS = (20, 40)  # the sensor reads that fail


class FlakyCamera:
    """A camera that delivers no frame at the `CAMERA_FAILS` captures (as V4L2 does on a bad cable)."""

    def __init__(self, camera: Any) -> None:
        self.camera, self.calls = camera, 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.camera, name)

    def capture(self, exposure_s: float, gain_db: float) -> Any:
        self.calls += 1
        if self.calls in CAMERA_FAILS:
            raise CaptureFailed("camera B (/dev/video0) delivered no frame; check the cable")
        return self.camera.capture(exposure_s, gain_db)


class FlakySensors:
    """Sensors whose bus fails at the `SENSOR_FAILS` reads (an I2C glitch raises OSError)."""

    def __init__(self, sensors: Any) -> None:
        self.sensors, self.calls = sensors, 0

    def read(self) -> Any:
        self.calls += 1
        if self.calls in SENSOR_FAILS:
            raise OSError(121, "Remote I/O error")
        return self.sensors.read()


def alarms(svc: IngestService) -> dict[str, Alarm]:
    with svc.store.read() as s:
        return {a.kind: a for a in s.scalars(select(Alarm).where(Alarm.module_id == "B"))}


def test_a_failing_camera_or_sensor_is_retried_counted_and_alarmed_and_the_module_goes_on(
    service: IngestService, tmp_path: Path
) -> None:
    agent = make_agent("B", service.endpoint, tmp_path / "outbox")[0]
    agent.runner.camera = FlakyCamera(agent.runner.camera)
    agent.sensors = FlakySensors(agent.sensors)
    agent.start()
    try:
        assert wait_for(lambda: agent.counters["frames_captured"] >= 8, 30), agent.counters
        assert wait_for(lambda: agent.sensors.calls > max(SENSOR_FAILS) + 5, 30)
        assert not agent.stopped
        assert agent.counters["capture_errors"] == len(CAMERA_FAILS)
        assert agent.counters["sensor_errors"] == len(SENSOR_FAILS)

        def said() -> bool:
            h = service.health()["modules"].get("B", {})
            return h.get("capture_errors") == len(CAMERA_FAILS) and h.get("sensor_errors") == len(
                SENSOR_FAILS
            )

        assert wait_for(said, 10), service.health()["modules"]
        assert service.health()["modules"]["B"]["link"] == "up"
        assert wait_for(lambda: {"camera", "sensors"} <= set(alarms(service)), 10), alarms(service)
        raised = alarms(service)
        assert raised["camera"].severity == "MAJOR" and "3 time(s)" in raised["camera"].message
        assert "check the camera's cable" in raised["camera"].message
        assert "leak" in raised["sensors"].message and "OSError" in raised["sensors"].message
        captured = agent.counters["frames_captured"]
        assert wait_for(lambda: agent.counters["frames_captured"] > captured + 3, 10)  # it goes on
    finally:
        agent.stop()
