"""What a module takes, into its SD card first: the frame and sensor half of `lrm.agent.Agent`.

Every frame and sensor message is numbered and written to the outbox before
it is offered to the ship. A number is used only once the card holds the
message (`Producing._keep`): a message the card cannot keep (full, failing)
is not taken and gives its number back, so the ship sees no gap, and the
module goes on (the heartbeat says how many it could not keep).
A camera or sensor read that fails (a loose cable, a bus glitch) is counted,
said in the heartbeat and tried again (`Producing._device_failed`): the
module does not stop for it. `Producing` is mixed into the agent, whose
state it uses.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections import Counter
from collections.abc import Callable
from datetime import timedelta
from typing import Any

from camcal.core.images import encode_png
from camcal.core.ratelog import RateLimitedLog
from lrm.camera import CameraError
from lrm.outbox import Outbox
from lrm.runner import Capture

log = logging.getLogger("camcal.lrm")

#: The longest wait between tries of a camera or sensor that keeps failing.
DEVICE_RETRY_MAX_S = 10.0


class Producing:
    """The capture and sensor threads of a module agent (mixed into `lrm.agent.Agent`)."""

    config: Any
    boot: str
    outbox: Outbox
    counters: Counter[str]
    clock: Any
    sensors: Any | None
    depth: Callable[[], float | None] | None
    clock_error: timedelta  # (simulation only: a module clock that is off)
    _source: Callable[[threading.Event], Capture | None]
    _produce_stop: threading.Event
    _new: queue.SimpleQueue[tuple[str, int]]
    _seq: int
    _seq_lock: threading.RLock
    device_errors: dict[str, str]  # the card's, the camera's and the sensors' last failure (heartbeat)
    warn: RateLimitedLog  # the module's log, at most a line per 10 s of each kind
    _device_streak: dict[str, int]

    def _next_seq(self) -> int:
        with self._seq_lock:
            if self._seq == 0:
                self._seq = self.outbox.last_seq(self.boot)
            self._seq += 1
            return self._seq

    def _keep(self, what: str, count: str, write: Callable[..., object], *args: Any, **kwargs: Any) -> None:
        """Number a message, write it to the card (``write(boot, seq, *args, **kwargs)``, an outbox
        method), count it (``counters[count]``) and offer it to the ship; when the card cannot keep
        it, give the number back and say so."""
        with self._seq_lock:
            seq = self._next_seq()
            try:
                write(self.boot, seq, *args, **kwargs)
            except OSError as exc:
                self._seq -= 1
                self._card_failed(what, exc)
                return
        self.counters[count] += 1
        self._new.put((self.boot, seq))

    def _failed(self, device: str, count: str | None, error: str, message: str, *args: Any) -> None:
        """A device's failure (``card``, ``camera``, ``sensors``): counted (``counters[count]``, and
        the count given to ``message`` last; None: not counted), its ``error`` kept for the
        heartbeat, ``message`` (with ``args``) logged at most every 10 s per device. The module
        goes on."""
        if count is not None:
            self.counters[count] += 1
            args = (*args, self.counters[count])
        self.device_errors[device] = error[:200]
        self.warn(logging.ERROR, f"device:{device}", message, self.config.module, *args)

    def _card_failed(self, what: str, exc: OSError) -> None:
        self._failed(
            "card",
            "card_skipped",
            f"{what}: {exc.strerror or exc}",
            "module %s: the SD card cannot keep a %s (%s); %d not taken so far: free or swap the card "
            "(everything on it is kept)",
            what,
            exc,
        )

    def _card_record(self, what: str, write: Callable[..., object], *args: Any) -> None:
        """``write(*args)``: a record of the card that is not a message (an acknowledgement, a
        refusal, a command's state). A full card cannot stop the module for it: the record holds in
        memory, the heartbeat and the log say the card failed, and after a restart the ship makes
        it good (a message acknowledged is acknowledged again). Before, the full card's OSError
        ended the thread that sends, and with it the module."""
        try:
            write(*args)
        except OSError as exc:
            self._failed(
                "card",
                None,
                f"{what}: {exc.strerror or exc}",
                "module %s: the SD card cannot keep %s (%s): free or swap the card (the module goes on)",
                what,
                exc,
            )

    def _device_failed(self, device: str, exc: Exception) -> float:
        """A camera or sensor read that failed (a loose cable, a bus glitch): counted and said in the
        heartbeat (``capture_errors``/``camera_error``, ``sensor_errors``/``sensor_error``). Returns
        how long to wait before trying again: 1 s, doubling while it keeps failing, at most
        `DEVICE_RETRY_MAX_S`."""
        self._failed(
            device,
            "capture_errors" if device == "camera" else "sensor_errors",
            f"{type(exc).__name__}: {exc}",
            "module %s: the %s failed (%s); %d failure(s) since the boot, retrying by itself",
            device,
            exc,
        )
        streak = self._device_streak[device] = self._device_streak.get(device, 0) + 1
        return float(min(DEVICE_RETRY_MAX_S, 2 ** (streak - 1)))

    def _device_works(self, device: str) -> None:
        """A camera or sensor read that worked: its failure streak ends (the next failure is retried
        after 1 s again). The heartbeat keeps naming the last failure; the ship's alarm holds for a
        while after the failures stop rising (`ingest.alarms`)."""
        if self._device_streak.get(device):
            log.info("module %s: the %s works again", self.config.module, device)
        self._device_streak[device] = 0

    # ------------------------------------------------------------ capture
    def _capture_loop(self) -> None:
        while not self._produce_stop.is_set():
            try:
                cap = self._source(self._produce_stop)
            except (CameraError, OSError) as exc:  # the same shot is tried again
                self._produce_stop.wait(self._device_failed("camera", exc))
                continue
            except ValueError as exc:  # a setting the camera refuses (its ranges known only now): the
                # ship is told (camera alarm) and a schedule within them fixes it; the module goes on
                self._produce_stop.wait(self._device_failed("camera", exc))
                continue
            self._device_works("camera")
            if cap is None:
                return
            f = cap.frame
            png = f.png if getattr(f, "png", None) else encode_png(f.pixels, getattr(f, "bit_depth", None))
            depth = f.depth_m if f.depth_m is not None else (self.depth() if self.depth else None)

            self._keep(
                "frame",
                "frames_captured",
                self.outbox.add_frame,
                png,
                captured_at=f.captured_at + self.clock_error,
                camera=f.camera or self.config.module,
                wavelength_nm=cap.wavelength_nm,
                exposure_s=f.exposure_s,
                gain_db=f.gain_db,
                depth_m=depth,
                schedule_version=cap.schedule_version,
            )

    # ------------------------------------------------------------ sensors
    def _sensor_loop(self) -> None:
        period = 1.0 / self.config.sensor_rate_hz
        rows: list[list[float | None]] = []
        batch_start = self.clock.monotonic()
        next_t = self.clock.monotonic()
        sensors = self.sensors
        assert sensors is not None  # this loop runs only for a module with sensors
        while not self._produce_stop.is_set():
            try:
                s = sensors.read()
            except Exception as exc:  # a sensor's driver may raise anything: this sample is lost
                self._produce_stop.wait(self._device_failed("sensors", exc))
                next_t = self.clock.monotonic()
                continue
            self._device_works("sensors")
            if s is None:  # nothing to read yet: no sample
                next_t = self._sensor_wait(next_t + period)
                continue
            acc, gyro = s.acc_m_s2 or (None, None, None), s.gyro_dps or (None, None, None)
            rows.append(
                [
                    s.t.timestamp() + self.clock_error.total_seconds(),
                    s.temperature_c,
                    s.humidity_pct,
                    acc[0],
                    acc[1],
                    acc[2],
                    gyro[0],
                    gyro[1],
                    gyro[2],
                    s.depth_m,
                ]
            )
            if self.clock.monotonic() - batch_start >= self.config.sensor_batch_s:
                self._keep("sensors", "sensor_batches", self.outbox.add_sensors, rows)
                rows, batch_start = [], self.clock.monotonic()
            next_t = self._sensor_wait(next_t + period)

    def _sensor_wait(self, next_t: float) -> float:
        """Sleep until the next sample is due (the next due time; now, when it is late)."""
        wait = next_t - self.clock.monotonic()
        if wait > 0:
            self.clock.sleep(wait)
            return next_t
        return self.clock.monotonic()
