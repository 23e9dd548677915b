"""GenICam through Aravis: loading it, the cameras it sees (`list_cameras`), and the device clock.

Aravis is the open GenICam library; Python reaches it through PyGObject
(``pip install 'camcal[camera]'``) and its introspection data (Debian:
``gir1.2-aravis-0.8``). Without them `load_aravis` raises `AravisMissing`,
which says what to install: nothing else of a module needs them.
`lrm.cameras.aravis.AravisCamera` drives one camera.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

from lrm.camera import CameraUnavailable

#: Monochrome pixel formats a module takes, with their significant bits (unpacked: Mono10 to Mono16
#: arrive in 16-bit little-endian samples, LSB-aligned; they are stored MSB-aligned, as PNG keeps them).
PIXEL_FORMATS: dict[str, int] = {"Mono8": 8, "Mono10": 10, "Mono12": 12, "Mono14": 14, "Mono16": 16}
#: GenICam PFNC codes of those formats (what a buffer says it holds).
PFNC = {0x01080001: "Mono8", 0x01100003: "Mono10", 0x01100005: "Mono12", 0x01100025: "Mono14"}
PFNC[0x01100007] = "Mono16"
#: The Debian packages and the extra a camera needs (said by every error about a missing part).
INSTALL_HINT = (
    "apt install gir1.2-aravis-0.8 aravis-tools, then pip install 'camcal[camera]' (see docs/module.md)"
)
#: One discovery or open at a time in a process: Aravis' device list is global.
DISCOVERY = threading.Lock()


class AravisMissing(CameraUnavailable):
    """PyGObject or Aravis' introspection data is not installed."""


def load_aravis() -> Any:
    """The ``gi.repository.Aravis`` module, or `AravisMissing` saying what to install."""
    try:
        import gi
    except ImportError:
        raise AravisMissing(f"PyGObject (gi) is not installed: {INSTALL_HINT}") from None
    try:
        gi.require_version("Aravis", "0.8")
        from gi.repository import Aravis
    except (ValueError, ImportError) as exc:
        raise AravisMissing(f"Aravis 0.8 is not installed ({exc}): {INSTALL_HINT}") from None
    return Aravis


def glib_error() -> type[Exception]:
    from gi.repository import GLib

    return GLib.Error  # type: ignore[no-any-return]


@dataclass(frozen=True)
class CameraListing:
    """One GenICam camera as `list_cameras` sees it (``error``: it could not be opened to ask more)."""

    device_id: str
    model: str
    vendor: str
    serial: str
    protocol: str
    address: str
    pixel_formats: tuple[str, ...] = ()
    exposure_range_s: tuple[float, float] | None = None
    gain_range_db: tuple[float, float] | None = None
    sensor_px: tuple[int, int] | None = None
    temperature_c: float | None = None
    error: str | None = None


def devices(ar: Any) -> list[dict[str, Any]]:
    ar.update_device_list()
    out = []
    for i in range(ar.get_n_devices()):
        out.append(
            {
                "device_id": ar.get_device_id(i) or "",
                "model": ar.get_device_model(i) or "",
                "vendor": ar.get_device_vendor(i) or "",
                "serial": ar.get_device_serial_nbr(i) or "",
                "protocol": ar.get_device_protocol(i) or "",
                "address": ar.get_device_address(i) or "",
            }
        )
    return out


def list_cameras(details: bool = True) -> list[CameraListing]:
    """The GenICam cameras this computer sees; with ``details`` each is opened for its pixel formats,
    ranges, sensor size and temperature (a camera another process holds says so in ``error``)."""
    ar = load_aravis()
    failed = glib_error()
    out = []
    with DISCOVERY:
        for d in devices(ar):
            if not details:
                out.append(CameraListing(**d))
                continue
            try:
                cam = ar.Camera.new(d["device_id"])
                formats = tuple(cam.dup_available_pixel_formats_as_strings() or ())
                e = cam.get_exposure_time_bounds()
                g = cam.get_gain_bounds()
                sensor = cam.get_sensor_size()
                temp = cam.get_float("DeviceTemperature") if has_feature(cam, "DeviceTemperature") else None
                out.append(
                    CameraListing(
                        **d,
                        pixel_formats=formats,
                        exposure_range_s=(seconds_from_us(e[0]), seconds_from_us(e[1])),
                        gain_range_db=(float(g[0]), float(g[1])),
                        sensor_px=(int(sensor[0]), int(sensor[1])),
                        temperature_c=temp,
                    )
                )
                del cam
            except failed as exc:
                out.append(CameraListing(**d, error=error_text(exc)))
    return out


def seconds_from_us(us: float) -> float:
    """Seconds from a GenICam exposure in µs, without binary noise (12345 µs: 0.012345 s)."""
    return round(float(us) / 1e6, 12)


def has_feature(cam: Any, feature: str) -> bool:
    try:
        return bool(cam.is_feature_available(feature))
    except Exception:  # (an Aravis error: a feature the camera's description does not have)
        return False


def error_text(exc: BaseException) -> str:
    return str(getattr(exc, "message", None) or exc)


class DeviceClock:
    """Maps a camera's frame timestamps (ns of its own clock) to UTC.

    Each frame carries the device's timestamp and the host's (UTC, when its
    first packet arrived). Their difference is the clock offset plus the
    transfer's delay, which is never negative: the smallest difference over
    the last ``window`` frames is the offset's estimate (as NTP keeps its
    least delayed sample). A camera without timestamps (0), or one whose
    mapped time falls outside the capture's own window (a device clock that
    was reset), gives None: the capture then uses the host's trigger time.
    """

    def __init__(self, window: int = 32) -> None:
        self._offsets: deque[int] = deque(maxlen=window)

    def reset(self) -> None:
        self._offsets.clear()

    def to_utc(self, device_ns: int, host_ns: int) -> datetime | None:
        if device_ns <= 0 or host_ns <= 0:
            return None
        self._offsets.append(host_ns - device_ns)
        return datetime.fromtimestamp((device_ns + min(self._offsets)) / 1e9, UTC)
