"""A GenICam camera (USB3 Vision, GigE Vision) through Aravis: `AravisCamera`.

A capture sets ExposureTime (µs) and Gain (dB) where they changed, reads
them back (the frame records what the camera applied, after its own
rounding), fires a software trigger and waits for the frame. A frame that
arrives incomplete (packets lost on the link) is never stored: the shot is
taken again, up to ``retries`` times, then `CaptureFailed`. A camera that
stops answering is `CameraUnavailable`; the next capture looks for it again
(by its id) and opens it anew, so a module picks its camera up when it comes
back. The device's frame timestamps are mapped to UTC through the host's
clock (`lrm.cameras.genicam.DeviceClock`). Loading Aravis and listing cameras:
`lrm.cameras.genicam`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from dataclasses import dataclass
from datetime import UTC, datetime, timedelta
from types import TracebackType
from typing import Any, Self

import numpy as np

from camcal.core.schedule import CameraLimits
from lrm.camera import (
    CameraClosed,
    CameraUnavailable,
    CapturedFrame,
    CaptureFailed,
    check_setting,
)
from lrm.cameras.genicam import (
    DISCOVERY,
    PFNC,
    PIXEL_FORMATS,
    AravisMissing,
    CameraListing,
    DeviceClock,
    devices,
    error_text,
    glib_error,
    has_feature,
    list_cameras,
    load_aravis,
    seconds_from_us,
)
from lrm.clock import Clock, SystemClock

log = logging.getLogger("camcal.lrm")


@dataclass
class _Applied:
    exposure_us: float = math.nan
    gain_db: float = math.nan
    asked: tuple[float, float] | None = None


class AravisCamera:
    """A GenICam camera (USB3 Vision, GigE Vision) through Aravis.

    Parameters
    ----------
    device
        The camera's Aravis id (``Aravis-Fake-GV01``, ``Basler-40012345``), its serial number or
        its address (`list_cameras`; ``camcal lrm cameras``).
    camera_id
        The module's id, written into every frame.
    pixel_format
        ``Mono8`` (default), ``Mono10``, ``Mono12``, ``Mono14`` or ``Mono16`` (unpacked); the camera
        must offer it. Deeper formats come as ``uint16`` frames, MSB-aligned, with their bits.
    width_px, height_px
        The region read out, centred on the sensor (default: the whole sensor).
    frame_timeout_s
        How long past the exposure a frame may take to arrive.
    packet_size_b
        GigE Vision only: the GVSP packet size in bytes (8000 or so with jumbo frames on the
        link; default: the camera's own). Set before the stream is made: Aravis places each
        packet's bytes by the size it was told, so a size changed under a running stream gives
        frames that read complete but hold their bytes in the wrong places.
    retries
        Shots taken again after an incomplete frame or a timeout before `CaptureFailed`.
    wait
        A camera not there yet is no error: the first capture looks for it (and raises
        `CameraUnavailable` while it is away); its ranges are known once it was opened
        (``connected``; `limits` is None before). A module started before its camera is
        powered runs, and the ship shows why it takes no frames.
    """

    def __init__(
        self,
        device: str,
        camera_id: str = "A",
        *,
        clock: Clock | None = None,
        pixel_format: str = "Mono8",
        width_px: int | None = None,
        height_px: int | None = None,
        frame_timeout_s: float = 3.0,
        retries: int = 2,
        buffers: int = 3,
        packet_size_b: int | None = None,
        wait: bool = False,
    ) -> None:
        if pixel_format not in PIXEL_FORMATS:
            raise ValueError(f"pixel_format must be one of {', '.join(PIXEL_FORMATS)}, got {pixel_format!r}")
        if not (frame_timeout_s > 0 and math.isfinite(frame_timeout_s)) or retries < 0 or buffers < 1:
            raise ValueError("frame_timeout_s must be > 0, retries >= 0 and buffers >= 1")
        if packet_size_b is not None and packet_size_b <= 0:
            raise ValueError(f"packet_size_b must be > 0, got {packet_size_b}")
        self.device = device
        self.camera_id = camera_id
        self.clock: Clock = clock or SystemClock()
        self.pixel_format = pixel_format
        self.bit_depth = PIXEL_FORMATS[pixel_format]
        self.requested_px = (width_px, height_px)
        self.frame_timeout_s = float(frame_timeout_s)
        self.retries = int(retries)
        self.n_buffers = int(buffers)
        self.packet_size_b = packet_size_b
        self.device_clock = DeviceClock()
        self.counters: dict[str, int] = {"incomplete": 0, "timeouts": 0, "stale": 0, "reopened": 0}
        self.temperature_c: float | None = None
        self._lock = threading.Lock()
        self._closed = False
        self._cam: Any = None
        self._stream: Any = None
        self._applied = _Applied()
        self._ar = load_aravis()
        self._glib_error = glib_error()
        self.device_id = device
        self.exposure_range_s = self.gain_range_db = (math.nan, math.nan)
        self.gain_step_db = 0.0
        self.has_temperature = False
        self.ever_opened = False
        try:
            self._open()
        except CameraUnavailable as exc:
            if not wait:
                raise
            log.warning("%s; the module looks for it again at every shot", exc)

    # ------------------------------------------------------------ opening
    def _find(self) -> str:
        seen = devices(self._ar)
        for key in ("device_id", "serial", "address"):
            for d in seen:
                if d[key] == self.device:
                    return d["device_id"]
        names = ", ".join(d["device_id"] for d in seen) or "none"
        raise CameraUnavailable(
            f"camera {self.camera_id}: no GenICam camera {self.device!r} is seen (cameras seen: {names}); "
            "check its cable and power (a GigE camera: its network and address), then "
            "`camcal lrm cameras`"
        )

    def _open(self) -> None:
        with DISCOVERY:
            device_id = self._find()
            try:
                cam = self._ar.Camera.new(device_id)
            except self._glib_error as exc:
                raise CameraUnavailable(
                    f"camera {self.camera_id}: {device_id} is seen but cannot be opened ({error_text(exc)}); "
                    "is another program using it (arv-viewer, another camcal)?"
                ) from None
        try:
            self._configure(cam, device_id)
        except self._glib_error as exc:
            raise CameraUnavailable(
                f"camera {self.camera_id}: {device_id} refused its set-up ({error_text(exc)})"
            ) from None
        self._cam = cam
        self.device_clock.reset()
        self._applied = _Applied()
        self.ever_opened = True

    def _configure(self, cam: Any, device_id: str) -> None:
        ar = self._ar
        self.device_id = device_id
        self.model = f"{cam.get_vendor_name() or ''} {cam.get_model_name() or ''}".strip()
        self.serial = cam.get_device_serial_number() or ""
        formats = tuple(cam.dup_available_pixel_formats_as_strings() or ())
        if self.pixel_format not in formats:
            mono = [f for f in formats if f in PIXEL_FORMATS]
            raise ValueError(
                f"camera {self.camera_id} ({device_id}) has no pixel format {self.pixel_format}; "
                f"it offers {', '.join(mono) or 'no monochrome format'}"
            )
        if cam.is_exposure_auto_available():
            cam.set_exposure_time_auto(ar.Auto.OFF)
        if cam.is_gain_auto_available():
            cam.set_gain_auto(ar.Auto.OFF)
        cam.set_pixel_format_from_string(self.pixel_format)
        sw, sh = cam.get_sensor_size()
        w, h = self.requested_px[0] or sw, self.requested_px[1] or sh
        if not (0 < w <= sw and 0 < h <= sh):
            raise ValueError(f"camera {self.camera_id}: region {w} x {h} px exceeds the sensor's {sw} x {sh}")
        cam.set_region(0, 0, w, h)  # offsets first to 0, so that the full size is allowed
        cam.set_region((sw - w) // 2, (sh - h) // 2, w, h)
        region = cam.get_region()
        self.width_px, self.height_px = int(region[2]), int(region[3])
        self.sensor_px = (int(sw), int(sh))
        e = cam.get_exposure_time_bounds()
        g = cam.get_gain_bounds()
        self.exposure_range_s = (seconds_from_us(e[0]), seconds_from_us(e[1]))
        self.gain_range_db = (float(g[0]), float(g[1]))
        self.gain_step_db = self._gain_step(cam)
        self.has_temperature = has_feature(cam, "DeviceTemperature")
        self.triggered = bool(cam.is_software_trigger_supported())
        if self.packet_size_b is not None:
            if not cam.is_gv_device():
                raise ValueError(f"camera {self.camera_id} ({device_id}) is no GigE camera: no packet size")
            cam.gv_set_packet_size(self.packet_size_b)
            self.packet_size_b = int(cam.gv_get_packet_size())
        if self.triggered:  # the camera waits for our trigger; one stream for the camera's life
            cam.set_trigger("Software")
            cam.set_acquisition_mode(ar.AcquisitionMode.CONTINUOUS)
            stream = cam.create_stream(None, None)
            payload = cam.get_payload()
            for _ in range(self.n_buffers):
                stream.push_buffer(ar.Buffer.new_allocate(payload))
            cam.start_acquisition()
            self._stream = stream

    def _gain_step(self, cam: Any) -> float:
        for name, get in (("Gain", cam.get_float_increment), ("GainRaw", cam.get_integer_increment)):
            if has_feature(cam, name):
                try:
                    return float(get(name))
                except self._glib_error:
                    continue
        return 0.0

    def _drop(self) -> None:
        """Let go of a camera that stopped answering (its stream and handle)."""
        cam, self._cam, self._stream = self._cam, None, None
        if cam is not None:
            with contextlib.suppress(self._glib_error):
                cam.stop_acquisition()
        del cam

    # ------------------------------------------------------------ capturing
    def capture(self, exposure_s: float, gain_db: float) -> CapturedFrame:
        with self._lock:
            if self._closed:
                raise CameraClosed(f"camera {self.camera_id} ({self.device}) is closed")
            if self._cam is None:
                again = self.ever_opened
                self._open()  # CameraUnavailable while it is still away
                self.counters["reopened"] += again
                log.warning(
                    "camera %s: %s is %s", self.camera_id, self.device_id, "back" if again else "here"
                )
            check_setting(exposure_s, gain_db, self.exposure_range_s, self.gain_range_db)
            try:
                return self._capture(exposure_s, gain_db)
            except self._glib_error as exc:
                self._drop()
                raise CameraUnavailable(
                    f"camera {self.camera_id} ({self.device_id}) stopped answering ({error_text(exc)}); "
                    "the module opens it again when it is back: check its cable and power"
                ) from None

    def _apply(self, exposure_s: float, gain_db: float) -> None:
        a = self._applied
        if a.asked == (exposure_s, gain_db):
            return
        cam = self._cam
        cam.set_exposure_time(exposure_s * 1e6)
        cam.set_gain(gain_db)
        self._applied = _Applied(cam.get_exposure_time(), cam.get_gain(), (exposure_s, gain_db))

    def _capture(self, exposure_s: float, gain_db: float) -> CapturedFrame:
        self._apply(exposure_s, gain_db)
        timeout_us = int((exposure_s + self.frame_timeout_s) * 1e6)
        problems: list[str] = []
        for _ in range(1 + self.retries):
            began = datetime.now(UTC)
            buf = self._one_buffer(timeout_us)
            if buf is None:
                self.counters["timeouts"] += 1
                self._cam.get_exposure_time()  # a camera gone raises here: CameraUnavailable
                problems.append(f"no frame within {timeout_us / 1e6:g} s")
                continue
            try:
                status = buf.get_status()
                if status != self._ar.BufferStatus.SUCCESS:
                    self.counters["incomplete"] += 1
                    problems.append(f"incomplete frame ({status.value_nick})")
                    continue
                return self._frame(buf, began)
            finally:
                if self._stream is not None:
                    self._stream.push_buffer(buf)
        raise CaptureFailed(
            f"camera {self.camera_id} ({self.device_id}): {len(problems)} tries, "
            f"{'; '.join(problems)}; nothing stored. Lost packets: check the cable or network "
            "(GigE: jumbo frames, packet size)"
        )

    def _one_buffer(self, timeout_us: int) -> Any:
        """The frame of one software trigger, or None when none came within ``timeout_us``.

        A frame of an earlier try that timed out may still be on its way, taken with that try's
        settings: one whose first packet arrived before this trigger (Aravis stamps it with the
        host's clock) cannot answer it, and is given back unread (``stale``)."""
        if self._stream is None:  # no software trigger: one acquisition per shot
            return self._cam.acquisition(timeout_us)
        while (stale := self._stream.try_pop_buffer()) is not None:  # a late frame of an earlier try
            self.counters["stale"] += 1
            self._stream.push_buffer(stale)
        triggered_ns = time.time_ns() // 1000 * 1000  # (Aravis' stamps are whole µs)
        self._cam.software_trigger()
        deadline = time.monotonic() + timeout_us / 1e6
        while (left_us := int((deadline - time.monotonic()) * 1e6)) > 0:
            buf = self._stream.timeout_pop_buffer(left_us)
            if buf is None or buf.get_system_timestamp() >= triggered_ns:
                return buf
            self.counters["stale"] += 1
            self._stream.push_buffer(buf)
        return None

    def _frame(self, buf: Any, began: datetime) -> CapturedFrame:
        fmt = PFNC.get(buf.get_image_pixel_format())
        if fmt != self.pixel_format:
            raise CaptureFailed(
                f"camera {self.camera_id} delivered pixel format {fmt or hex(buf.get_image_pixel_format())}, "
                f"not {self.pixel_format}"
            )
        w, h = buf.get_image_width(), buf.get_image_height()
        data = buf.get_image_data()
        bits = PIXEL_FORMATS[fmt]
        size = 1 if bits == 8 else 2
        if len(data) < w * h * size:
            raise CaptureFailed(f"camera {self.camera_id}: frame of {len(data)} bytes for {w} x {h} px")
        rows = np.frombuffer(data, np.uint8)[: (len(data) // h) * h].reshape(h, -1)[:, : w * size]
        if bits == 8:
            pixels = rows.copy()
        else:
            pixels = rows.copy().view("<u2").astype(np.uint16)
            if bits < 16:
                np.minimum(pixels, (1 << bits) - 1, out=pixels)
                pixels <<= 16 - bits
        received = datetime.now(UTC)
        stamped = self.device_clock.to_utc(buf.get_timestamp(), buf.get_system_timestamp())
        slack = timedelta(seconds=1)
        captured = stamped if stamped is not None and began - slack <= stamped <= received + slack else began
        a = self._applied
        if self.has_temperature:
            try:
                self.temperature_c = float(self._cam.get_float("DeviceTemperature"))
            except self._glib_error as exc:  # the frame is good: only its temperature is unknown
                log.warning("camera %s: DeviceTemperature unread (%s)", self.camera_id, error_text(exc))
                self.temperature_c = None
        return CapturedFrame(
            pixels=pixels,
            captured_at=captured,
            exposure_s=seconds_from_us(a.exposure_us),
            gain_db=float(a.gain_db),
            camera=self.camera_id,
            bit_depth=bits,
            extra={
                "device": self.device_id,
                "device_timestamp_ns": int(buf.get_timestamp()),
                "host_timestamp_ns": int(buf.get_system_timestamp()),  # (its first packet here, UTC)
                "frame_id": int(buf.get_frame_id()),
                "timestamp_source": "device" if captured is stamped else "host",
                "requested_exposure_s": a.asked[0] if a.asked else None,
                "requested_gain_db": a.asked[1] if a.asked else None,
                "device_temperature_c": self.temperature_c,
                "latency_s": (received - began).total_seconds(),
            },
        )

    # ------------------------------------------------------------ state
    def limits(self) -> CameraLimits | None:
        """The ranges the camera takes (None until it was opened once)."""
        if not self.ever_opened:
            return None
        return CameraLimits(self.exposure_range_s, self.gain_range_db, self.gain_step_db)

    def info(self) -> dict[str, Any] | None:
        """What the ship is told of this camera (`camcal.core.wire.CameraInfo`'s fields; None until
        it was opened once)."""
        if not self.ever_opened:
            return None
        return {
            "model": self.model[:120],
            "serial": self.serial[:64],
            "pixel_format": self.pixel_format,
            "bit_depth": self.bit_depth,
            "width_px": self.width_px,
            "height_px": self.height_px,
            "exposure_range_s": self.exposure_range_s,
            "gain_range_db": self.gain_range_db,
            "gain_step_db": self.gain_step_db,
        }

    def stream_statistics(self) -> dict[str, float]:
        """Aravis' counts of the stream: completed buffers, failures, missing packets, resends..."""
        with self._lock:
            stream = self._stream
            if stream is None:
                return {}
            out: dict[str, float] = {}
            for i in range(stream.get_n_infos()):
                name = stream.get_info_name(i)
                is_int = stream.get_info_type(i).name == "guint64"
                out[name] = stream.get_info_uint64(i) if is_int else stream.get_info_double(i)
            return out

    @property
    def connected(self) -> bool:
        return self._cam is not None

    def read_settings(self) -> tuple[float, float]:
        """(exposure_s, gain_db) as the camera's registers hold them now (for checks and tests)."""
        with self._lock:
            if self._cam is None:
                raise CameraUnavailable(f"camera {self.camera_id} is not connected")
            return seconds_from_us(self._cam.get_exposure_time()), float(self._cam.get_gain())

    def close(self) -> None:
        with self._lock:
            self._closed = True
            self._drop()

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


__all__ = [
    "PIXEL_FORMATS",
    "AravisCamera",
    "AravisMissing",
    "CameraListing",
    "DeviceClock",
    "list_cameras",
    "load_aravis",
]
