"""The real GigE Vision emulator, ``arv-fake-gv-camera-0.8`` (Debian's ``aravis-tools``), for tests.

It serves a GenICam camera over GVCP/GVSP (UDP) on 127.0.0.1: Aravis talks to
it as to any GigE camera. GigE Vision fixes its control port (3956) and the
emulator binds only an address an interface has, so one emulator runs on this
machine at a time: `FakeGigECamera` holds a lock file for as long as it is
used (tests on other xdist workers wait for it). Each test gives it a serial
of its own, so that no test ever talks to another's camera.

Tests skip, saying what to install, where PyGObject, Aravis' introspection
data or the emulator is missing (`require_aravis`).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

EMULATOR = "arv-fake-gv-camera-0.8"
GVCP_PORT = 3956
LOCK = Path(tempfile.gettempdir()) / "camcal-arv-fake-gv-camera.lock"
#: How long a test waits for another worker's emulator to be done.
LOCK_WAIT_S = 600.0


def require_aravis() -> None:
    """Skip the test, saying what is missing, unless Aravis, PyGObject and the emulator are here."""
    from lrm.cameras.aravis import AravisMissing, load_aravis

    try:
        load_aravis()
    except AravisMissing as exc:
        pytest.skip(f"no Aravis here: {exc}")
    if shutil.which(EMULATOR) is None:
        pytest.skip(f"{EMULATOR} is not installed (apt install aravis-tools)")


#: The emulator's DeviceTemperature (it has none: `genicam_with_temperature` adds one) in °C: this
#: plus `TEMPERATURE_PER_GAIN_C` per dB of its gain, so that a reading follows the frame it came with.
TEMPERATURE_AT_0_DB_C = 30.5
TEMPERATURE_PER_GAIN_C = 0.25


def genicam_with_temperature(folder: Path) -> Path:
    """The emulator's own GenICam description with a ``DeviceTemperature`` added, written into
    ``folder`` for ``FakeGigECamera(genicam=...)``.

    The description comes from Aravis itself (its in-process fake camera, the same file the
    emulator serves); the temperature is a formula on the gain register, since the emulator keeps
    no other register that a test could move (its declared features must match its registers).
    """
    from lrm.cameras.genicam import DISCOVERY, load_aravis

    ar = load_aravis()
    with DISCOVERY:
        ar.enable_interface("Fake")
        try:
            ar.update_device_list()
            xml = ar.Camera.new("Fake_1").get_device().get_genicam_xml()[0]
        finally:
            ar.disable_interface("Fake")
            ar.update_device_list()
    node = (
        '<Float Name="DeviceTemperature" NameSpace="Standard"><pValue>DeviceTemperatureFormula</pValue>'
        "<Unit>C</Unit></Float>"
        '<SwissKnife Name="DeviceTemperatureFormula" NameSpace="Custom">'
        '<pVariable Name="GAIN">GainRaw</pVariable>'
        f"<Formula>{TEMPERATURE_AT_0_DB_C} + {TEMPERATURE_PER_GAIN_C} * GAIN</Formula></SwissKnife>"
    )
    assert xml.count("</RegisterDescription>") == 1 and "<pFeature>DeviceVendorName</pFeature>" in xml
    xml = xml.replace("</RegisterDescription>", node + "</RegisterDescription>").replace(
        "<pFeature>DeviceVendorName</pFeature>",
        "<pFeature>DeviceVendorName</pFeature><pFeature>DeviceTemperature</pFeature>",
    )
    path = folder / "fake-camera-with-temperature.xml"
    path.write_text(xml)
    return path


def whole_ramp(pixels: np.ndarray, frame_id: int | None = None) -> bool:
    """Whether a frame is the emulator's picture in every pixel, at 10 ms and 0 dB (its scale 1): a
    diagonal ramp, (x + y + frame id) mod 255 in Mono8, 256 (x + y + frame id) mod 65535 in Mono16
    (Aravis' arvfakecamera.c); without ``frame_id``, the ramp that starts at the first pixel's
    value. A frame with a packet missing or misplaced (a buffer's old bytes left) is no ramp."""
    h, w = pixels.shape
    step, period = (256, 65535) if pixels.dtype == np.uint16 else (1, 255)
    first = int(pixels[0, 0]) if frame_id is None else step * frame_id % period
    ramp = (first + step * np.add.outer(np.arange(h), np.arange(w))) % period
    return bool(np.array_equal(pixels, ramp))


def _port_bound() -> bool:
    """Whether something serves GVCP on 127.0.0.1 (its port cannot be bound)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", GVCP_PORT))
    except OSError as exc:
        return exc.errno == errno.EADDRINUSE
    finally:
        s.close()
    return False


class FakeGigECamera:
    """The emulator as a process of the test: start, kill (a camera unplugged), start again."""

    def __init__(
        self, lost_per_thousand: int = 0, serial: str | None = None, genicam: Path | None = None
    ) -> None:
        require_aravis()
        self.serial = serial or f"T{secrets.token_hex(3).upper()}"
        self.lost_per_thousand = lost_per_thousand
        self.genicam = genicam  # a GenICam description of its own (`genicam_with_temperature`)
        self.proc: subprocess.Popen[bytes] | None = None
        self._lock_fd: int | None = None

    @property
    def device_id(self) -> str:
        return f"Aravis-Fake-{self.serial}"

    def _lock(self) -> None:
        fd = os.open(LOCK, os.O_RDWR | os.O_CREAT, 0o666)
        end = time.monotonic() + LOCK_WAIT_S
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() > end:
                    os.close(fd)
                    raise TimeoutError(
                        f"the GigE emulator's lock {LOCK} stayed taken {LOCK_WAIT_S:.0f} s"
                    ) from None
                time.sleep(0.2)
        self._lock_fd = fd

    def start(self) -> FakeGigECamera:
        if self._lock_fd is None:
            self._lock()
        end = time.monotonic() + 10.0
        while _port_bound():  # (the last emulator's socket, closing)
            if time.monotonic() > end:
                raise RuntimeError(f"127.0.0.1:{GVCP_PORT} stays taken by another program: stop it")
            time.sleep(0.1)
        args = [EMULATOR, "-i", "127.0.0.1", "-s", self.serial]
        if self.lost_per_thousand:
            args += ["-r", str(self.lost_per_thousand)]
        if self.genicam is not None:
            args += ["-g", str(self.genicam)]
        self.proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        while not _port_bound():
            if self.proc.poll() is not None:
                err = self.proc.stderr.read().decode(errors="replace") if self.proc.stderr else ""
                raise RuntimeError(f"{EMULATOR} exited at once: {err.strip()}")
            if time.monotonic() > end:
                raise RuntimeError(f"{EMULATOR} did not bind 127.0.0.1:{GVCP_PORT} within 10 s")
            time.sleep(0.05)
        return self

    def kill(self) -> None:
        """Gone at once, as a camera whose cable is pulled (SIGKILL: no goodbye on the wire)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGKILL)
            self.proc.wait(10)
        if self.proc is not None and self.proc.stderr:
            self.proc.stderr.close()
        self.proc = None

    def close(self) -> None:
        self.kill()
        if self._lock_fd is not None:
            with contextlib.suppress(OSError):
                fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            os.close(self._lock_fd)
            self._lock_fd = None

    def __enter__(self) -> FakeGigECamera:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
