"""`camcal lrm run` as systemd runs it (deploy/camcal-lrm.service): configured from its environment
file's variables, it says READY=1, feeds the watchdog while its agent works, streams its camera's
frames and its camera's DeviceTemperature (as the housing temperature) to the ship, and stops
cleanly on SIGTERM. systemd's notify socket is a real datagram socket of the test; the camera is the
GigE Vision emulator (given a DeviceTemperature: `genicam_with_temperature`), the ship a real ingest.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from sqlalchemy import select

from camcal.core.schedule import Schedule
from ingest.service import IngestService
from storage.models import SensorSample
from tests.live.conftest import ingest_config
from tests.utils.aravis import (
    TEMPERATURE_AT_0_DB_C,
    TEMPERATURE_PER_GAIN_C,
    FakeGigECamera,
    genicam_with_temperature,
)
from tests.utils.live import wait_for


def test_the_module_service_is_ready_feeds_its_watchdog_streams_and_stops(tmp_path: Path) -> None:
    svc = IngestService(ingest_config(tmp_path / "data"))
    svc.start()
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify.sock"))
    notify.settimeout(0.2)
    sched = Schedule(name="bench", exposures_s=(0.01,), gains_db=(2.0,), repeats=1, wavelengths_nm=(460,))
    (tmp_path / "bench.json").write_text(sched.model_dump_json())
    said: list[tuple[float, str]] = []

    def hear(until: float) -> None:
        while time.monotonic() < until:
            with contextlib.suppress(TimeoutError):
                said.append((time.monotonic(), notify.recv(4096).decode()))

    def housing_c() -> list[float | None]:
        with svc.store.read() as s:
            return list(s.scalars(select(SensorSample.temperature_c).where(SensorSample.module_id == "A")))

    camera = FakeGigECamera(genicam=genicam_with_temperature(tmp_path))
    with camera as gige, (tmp_path / "module.log").open("wb") as log:
        env = {  # what /etc/camcal/lrm.env and systemd give it
            **os.environ,
            "PYTHONPATH": ".",
            "NOTIFY_SOCKET": str(tmp_path / "notify.sock"),
            "WATCHDOG_USEC": "1000000",
            "CAMCAL_LRM_MODULE": "A",
            "CAMCAL_LRM_CAMERA": f"aravis:{gige.serial}",
            "CAMCAL_LRM_CONNECT": svc.endpoint,
            "CAMCAL_LRM_SCHEDULE": str(tmp_path / "bench.json"),
            "CAMCAL_LINK_PLAINTEXT": "true",
        }
        cmd = [sys.executable, "-m", "camcal", "lrm", "run", "--outbox", str(tmp_path / "outbox")]
        proc = subprocess.Popen(
            [*cmd, "--width-px", "160", "--height-px", "120"], env=env, stdout=log, stderr=log
        )
        try:
            assert wait_for(lambda: svc.counters["frames_stored"] >= 3, 60), (
                tmp_path / "module.log"
            ).read_text()
            # the camera's temperature as the housing's, from its first frame (none sent before):
            # the module sends its sensors every 10 s
            assert wait_for(lambda: len(housing_c()) >= 3, 60), (tmp_path / "module.log").read_text()
            hear(time.monotonic() + 2.0)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(30) == 0, (tmp_path / "module.log").read_text()[-2000:]
            hear(time.monotonic() + 0.5)
        finally:
            if proc.poll() is None:
                proc.kill()
            notify.close()
            svc.stop()
    states = [m.split("\n")[0] for _, m in said]
    assert "READY=1" in states, said
    pings = [t for t, m in said if m.startswith("WATCHDOG=1")]
    assert len(pings) >= 4 and max(b - a for a, b in itertools.pairwise(pings)) < 1.0, said
    assert states[-1] == "STOPPING=1"
    status = [m for _, m in said if "STATUS=" in m][-1]
    assert "frames" in status and "linked" in status, status
    assert set(housing_c()) == {TEMPERATURE_AT_0_DB_C + 2.0 * TEMPERATURE_PER_GAIN_C}  # at 2 dB
