"""Camera and sensor backends: the simulated ones, and the V4L2 one without hardware."""

from __future__ import annotations

import itertools
import time
from datetime import timedelta

import cv2
import numpy as np
import pytest

from lrm.camera import (
    CameraBackend,
    CameraClosed,
    CameraUnavailable,
    CapturedFrame,
    CaptureFailed,
    SensorBackend,
    SimulatedCamera,
    SimulatedSensors,
)
from lrm.cameras.v4l2 import (
    V4L2Camera,
    exposure_from_device,
    exposure_to_device,
    gain_from_device,
    gain_to_device,
    to_mono8,
)
from lrm.clock import SimClock
from lrm.dive import DiveSimulation
from tests.utils.dive import short_dive
from tests.utils.pace import Pace

SPEED = 20.0


def station_clock(sim: DiveSimulation, into_s: float = 30.0, speed: float = SPEED) -> SimClock:
    """A simulated clock standing ``into_s`` seconds into the station."""
    t0, _ = sim.profile.window("station")
    return SimClock(sim.time_at(t0 + into_s), speed=speed)


# -- SimulatedCamera ---------------------------------------------------------------------


def test_simulated_capture_takes_exposure_plus_readout_and_carries_metadata() -> None:
    """A capture waits its exposure and readout once, and otherwise only for its own work.

    At real speed (1×) the rendering's time is the computer's, not the simulation's: what the capture
    took beyond its CPU time is its wait, plus what the machine keeps it waiting for a core (`Pace`).
    """
    sim = short_dive(1)
    clock = station_clock(sim, speed=1.0)
    camera = SimulatedCamera(sim, "B", clock, readout_s=0.8)
    assert isinstance(camera, CameraBackend)
    camera.capture(0.02, 2.0)  # the first capture in a water state also builds its renderer
    pace = Pace()
    before, before_utc, cpu0 = clock.monotonic(), clock.now(), time.process_time()
    frame = camera.capture(0.11, 8.04)
    took, cpu_s = clock.monotonic() - before, time.process_time() - cpu0
    assert before_utc <= frame.captured_at <= before_utc + timedelta(seconds=took - 0.91)
    assert took >= 0.11 + 0.8
    # not waited twice (that would be another 0.91 s), however long the rendering took
    assert took - cpu_s < 0.91 + pace.bound(0.25), (took, cpu_s, str(pace))
    assert isinstance(frame, CapturedFrame)
    assert frame.pixels.shape == (512, 612) and frame.pixels.dtype == np.uint8
    assert frame.camera == "B"
    assert frame.exposure_s == 0.11
    assert frame.gain_db == pytest.approx(8.0)  # the camera's 0.1 dB steps
    t_s = sim.dive_time_s(frame.captured_at)
    assert frame.wavelength_nm == sim.timetable.wavelength_at(t_s)
    assert frame.depth_m == pytest.approx(3420 - 41.62, abs=0.5)
    assert frame.extra["phase"] == "station"
    assert frame.extra["lambda_att_m"] == pytest.approx(
        sim.lambda_att_truth_m("B", frame.wavelength_nm, t_s), rel=3e-3
    )
    assert frame.captured_at.utcoffset() == timedelta(0)


def test_consecutive_captures_advance_dive_time_and_follow_the_lem() -> None:
    sim = short_dive(2)
    t0, _ = sim.profile.window("station")
    change = sim.timetable.next_change_after(t0 + 30.0)
    clock = SimClock(sim.time_at(change - 1.5), speed=SPEED)
    camera = SimulatedCamera(sim, "A", clock, readout_s=0.8)
    frames = [camera.capture(0.02, 4.0) for _ in range(3)]
    times = [sim.dive_time_s(f.captured_at) for f in frames]
    assert all(b - a >= 0.82 for a, b in itertools.pairwise(times))
    assert [f.wavelength_nm for f in frames] == [sim.timetable.wavelength_at(t) for t in times]
    assert frames[0].wavelength_nm != frames[-1].wavelength_nm


def test_simulated_camera_checks_settings_and_closes() -> None:
    sim = short_dive()
    camera = SimulatedCamera(sim, "A", station_clock(sim, speed=1000.0), readout_s=0.0)
    with pytest.raises(ValueError, match="exposure_s"):
        camera.capture(5.0, 2.0)
    with pytest.raises(ValueError, match="gain_db"):
        camera.capture(0.02, 40.0)
    with pytest.raises(ValueError, match="module 'C'"):
        SimulatedCamera(sim, "C", station_clock(sim))
    camera.close()
    with pytest.raises(CameraClosed):
        camera.capture(0.02, 2.0)


def test_simulated_sensors_read_at_the_clock_time() -> None:
    sim = short_dive(3)
    clock = station_clock(sim, speed=1.0)
    sensors = SimulatedSensors(sim, "A", clock)
    assert isinstance(sensors, SensorBackend)
    sample = sensors.read()
    lag = (clock.now() - sample.t).total_seconds()
    assert 0.0 <= lag < 0.1 + 0.05  # the latest 10 Hz sample
    assert sample.module == "A"
    assert sample.acc_m_s2[2] == pytest.approx(9.81, abs=0.5)
    assert sample.to_dict()["t"].endswith("Z")  # type: ignore[union-attr]


# -- V4L2Camera --------------------------------------------------------------------------


def test_v4l2_without_a_camera_raises_a_clear_error() -> None:
    # No camera hardware on this machine: the real OpenCV backend must fail to open it.
    with pytest.raises(CameraUnavailable, match=r"camera A: .*/dev/video7.*plugged in"):
        V4L2Camera(7, camera_id="A", open_capture=cv2.VideoCapture)
    with pytest.raises(CameraUnavailable, match=r"/dev/video-missing does not exist"):
        V4L2Camera("/dev/video-missing", camera_id="B")


def test_v4l2_unit_conversions() -> None:
    assert exposure_to_device(0.02) == 200  # V4L2 counts 100 µs
    assert exposure_to_device(1.0) == 10000
    assert exposure_to_device(1e-6) == 1  # never 0
    assert exposure_from_device(700) == pytest.approx(0.07)
    assert gain_to_device(8.0) == 8
    assert gain_to_device(8.0, units_per_db=10.0) == 80
    assert gain_from_device(80, units_per_db=10.0) == pytest.approx(8.0)
    assert gain_from_device(gain_to_device(6.0, 3.0, 16.0), 3.0, 16.0) == pytest.approx(6.0)
    with pytest.raises(ValueError, match="exposure_s"):
        exposure_to_device(0.0)
    bgr = np.zeros((4, 5, 3), np.uint8)
    bgr[..., 1] = 200
    gray = to_mono8(bgr)
    assert gray.shape == (4, 5) and gray.dtype == np.uint8 and int(gray[0, 0]) == round(0.587 * 200)
    with pytest.raises(CaptureFailed, match="8-bit"):
        to_mono8(np.zeros((4, 5), np.uint16))


class FakeCapture:
    """A stand-in for `cv2.VideoCapture` that records what it is asked."""

    def __init__(self, frames: list[np.ndarray | None]) -> None:
        self.frames = frames
        self.props: dict[int, float] = {}
        self.sets: list[tuple[int, float]] = []
        self.reads = 0
        self.released = False

    def isOpened(self) -> bool:
        return True

    def set(self, prop: int, value: float) -> bool:
        self.sets.append((prop, value))
        self.props[prop] = value
        return True

    def get(self, prop: int) -> float:
        return self.props.get(prop, -1.0)

    def read(self) -> tuple[bool, np.ndarray | None]:
        self.reads += 1
        frame = self.frames.pop(0) if self.frames else None
        return frame is not None, frame

    def release(self) -> None:
        self.released = True


def test_v4l2_control_flow_against_a_fake_device() -> None:
    bgr = np.full((6, 8, 3), 50, np.uint8)
    fake = FakeCapture([bgr] * 3)
    camera = V4L2Camera(0, camera_id="B", gain_units_per_db=10.0, open_capture=lambda dev, api: fake)
    assert isinstance(camera, CameraBackend)
    assert fake.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1.0  # manual
    frame = camera.capture(0.05, 8.0)
    assert fake.props[cv2.CAP_PROP_EXPOSURE] == 500.0 and fake.props[cv2.CAP_PROP_GAIN] == 80.0
    assert fake.reads == 2  # one stale frame dropped after the change of setting
    assert frame.pixels.shape == (6, 8) and frame.exposure_s == pytest.approx(0.05)
    assert frame.gain_db == pytest.approx(8.0) and frame.camera == "B"
    assert frame.wavelength_nm is None and frame.extra["device"] == "/dev/video0"
    camera.capture(0.05, 8.0)
    assert fake.reads == 3  # same setting: nothing to drop
    with pytest.raises(ValueError, match="exposure_s"):
        camera.capture(2.0, 8.0)
    with pytest.raises(CaptureFailed, match="no frame"):
        camera.capture(0.02, 8.0)
    camera.close()
    assert fake.released
    with pytest.raises(CameraClosed):
        camera.capture(0.05, 8.0)


def test_camcal_lrm_run_without_the_device_says_what_to_check(tmp_path) -> None:
    from typer.testing import CliRunner

    from camcal.cli import app

    args = ["lrm", "run", "--camera", "v4l2:/dev/video-missing", "--outbox", str(tmp_path / "ob")]
    res = CliRunner().invoke(app, args)
    assert res.exit_code == 2, res.output
    assert "/dev/video-missing does not exist" in res.output and "v4l2-ctl" in res.output
    assert "Traceback" not in res.output
    bad = CliRunner().invoke(app, [*args, "--lem-epoch", "tomorrow"])
    assert bad.exit_code == 2 and "--lem-epoch" in bad.output
