"""Camera and sensor backends behind the interfaces the LRM agent uses.

* `CameraBackend`: ``capture(exposure_s, gain_db) -> CapturedFrame``, with the
  ranges the camera accepts. `SimulatedCamera` renders frames of a
  `lrm.dive.DiveSimulation` and takes as long as a real capture would; the
  real cameras are in `lrm.cameras`: `lrm.cameras.aravis.AravisCamera` (any
  GenICam camera: USB3 Vision, GigE Vision) and `lrm.cameras.v4l2.V4L2Camera`
  (a UVC camera through OpenCV).
* `SensorBackend`: ``read() -> SensorSample | None`` (None: nothing to say yet, no sample sent).
  `SimulatedSensors` reads a simulated module's housing sensors.

Errors are typed: `CameraUnavailable` when there is no camera to open,
`CaptureFailed` when a capture does not deliver a frame, `CameraClosed` after
`close`; all are `CameraError`. Settings out of range raise `ValueError`
naming the parameter.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from datetime import datetime
from types import TracebackType
from typing import TYPE_CHECKING, Any, Protocol, Self, runtime_checkable

import numpy as np

from lrm.clock import Clock
from lrm.sensors import SensorSample

if TYPE_CHECKING:  # the simulator (SciPy, the renderer) is not needed to drive a real camera
    from lrm.dive import DiveSimulation

log = logging.getLogger(__name__)


class CameraError(RuntimeError):
    """A camera could not do what was asked."""


class CameraUnavailable(CameraError):
    """No camera could be opened at the given device."""


class CaptureFailed(CameraError):
    """The camera was open but did not deliver a usable frame."""


class CameraClosed(CameraError):
    """The camera was used after `close`."""


@dataclass(frozen=True, eq=False)
class CapturedFrame:
    """One frame as a camera delivered it, with what is known about how it was taken.

    Attributes
    ----------
    pixels
        2-D array, ``[row, col]``: ``uint8`` for an 8-bit camera; ``uint16`` for 10 to 16 bits,
        MSB-aligned (a 12-bit value ``v`` is stored as ``v << 4``, as PNG keeps it), so that
        full scale is near 65535 whatever the depth.
    bit_depth
        Significant bits per pixel (8 for ``uint8``; 10, 12, 14 or 16 for ``uint16``): the
        frame's full scale and saturation level are ``(2**bit_depth - 1) << (16 - bit_depth)``.
    captured_at
        Start of the exposure, timezone-aware UTC.
    exposure_s, gain_db
        The setting the camera applied (after its own rounding).
    camera
        The camera's id (``"A"``, ``"B"``).
    wavelength_nm
        The LEM's wavelength during the exposure, if the camera knows it.
    depth_m
        The module's depth, if known.
    extra
        Backend-specific metadata (for the simulator: the frame's truth).

    Frames compare by identity (the pixels are an array).
    """

    pixels: np.ndarray
    captured_at: datetime
    exposure_s: float
    gain_db: float
    camera: str
    wavelength_nm: int | None = None
    depth_m: float | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    bit_depth: int = 8

    def __post_init__(self) -> None:
        px = self.pixels
        if not isinstance(px, np.ndarray) or px.ndim != 2 or px.dtype not in (np.uint8, np.uint16):
            raise ValueError(
                f"pixels must be a 2-D uint8 or uint16 array, got shape {getattr(px, 'shape', None)} "
                f"dtype {getattr(px, 'dtype', type(px).__name__)}"
            )
        if (px.dtype == np.uint8) != (self.bit_depth == 8) or not 8 <= self.bit_depth <= 16:
            raise ValueError(f"bit_depth {self.bit_depth} does not fit {px.dtype} pixels")
        if self.captured_at.tzinfo is None or self.captured_at.utcoffset() is None:
            raise ValueError(f"captured_at must be timezone-aware UTC, got {self.captured_at.isoformat()}")


@runtime_checkable
class CameraBackend(Protocol):
    """What the agent needs from a camera."""

    camera_id: str
    exposure_range_s: tuple[float, float]
    gain_range_db: tuple[float, float]
    gain_step_db: float

    def capture(self, exposure_s: float, gain_db: float) -> CapturedFrame: ...

    def close(self) -> None: ...


@runtime_checkable
class SensorBackend(Protocol):
    """What the agent needs from the housing sensors: a sample, or None when there is nothing to
    read yet (a camera's temperature before its first frame): no sample is sent then."""

    def read(self) -> SensorSample | None: ...


def check_setting(
    exposure_s: float,
    gain_db: float,
    exposure_range_s: tuple[float, float],
    gain_range_db: tuple[float, float],
) -> None:
    """Raise `ValueError` naming the parameter if a setting lies outside a camera's ranges."""
    lo, hi = exposure_range_s
    if not (math.isfinite(exposure_s) and lo <= exposure_s <= hi):
        raise ValueError(f"exposure_s {exposure_s} outside the camera's range [{lo}, {hi}] s")
    glo, ghi = gain_range_db
    if not (math.isfinite(gain_db) and glo <= gain_db <= ghi):
        raise ValueError(f"gain_db {gain_db} outside the camera's range [{glo}, {ghi}] dB")


def quantise_gain_db(gain_db: float, step_db: float, gain_range_db: tuple[float, float]) -> float:
    """The gain a camera with steps of ``step_db`` applies for a request of ``gain_db``."""
    if step_db <= 0:
        return float(gain_db)
    g = round(gain_db / step_db) * step_db
    return float(min(max(g, gain_range_db[0]), gain_range_db[1]))


class SimulatedCamera:
    """A module's camera in a simulated dive.

    ``capture`` renders the frame at the clock's current dive time (the
    exposure starts then), and takes as long as the real capture: it sleeps
    on the clock for the exposure plus ``readout_s`` (sensor readout and USB
    transfer of 5 MP; T-REX took ~3000 frames in 30 minutes over two cameras,
    about 1.2 s per frame each, schedule overhead included). Time spent
    rendering counts toward that sleep, so at high clock speeds a capture
    lasts at least as long as rendering it.

    The gain is rounded to ``gain_step_db`` as a real camera does; the frame
    reports the gain applied. ``extra`` holds the simulator's truth (see
    `DiveSimulation.render`).
    """

    def __init__(self, sim: DiveSimulation, module: str, clock: Clock, *, readout_s: float = 0.8) -> None:
        sim.placement(module)  # raises ValueError naming the module if unknown
        if not (readout_s >= 0 and math.isfinite(readout_s)):
            raise ValueError(f"readout_s must be a finite number >= 0, got {readout_s}")
        self.sim = sim
        self.module = module
        self.clock = clock
        self.readout_s = float(readout_s)
        self.camera_id = module
        self.exposure_range_s = sim.camera.exposure_range_s
        self.gain_range_db = sim.camera.gain_range_db
        self.gain_step_db = sim.camera.gain_step_db
        self._lock = threading.Lock()
        self._closed = False

    def capture(self, exposure_s: float, gain_db: float) -> CapturedFrame:
        check_setting(exposure_s, gain_db, self.exposure_range_s, self.gain_range_db)
        gain = quantise_gain_db(gain_db, self.gain_step_db, self.gain_range_db)
        with self._lock:
            if self._closed:
                raise CameraClosed(f"camera {self.camera_id} is closed")
            began = self.clock.monotonic()
            captured_at = self.clock.now()
            t_s = self.sim.dive_time_s(captured_at)
            pixels, meta = self.sim.render(self.module, t_s, exposure_s, gain)
            remaining = exposure_s + self.readout_s - (self.clock.monotonic() - began)
            if remaining > 0:
                self.clock.sleep(remaining)
        wavelength = meta["wavelength_nm"]
        depth = meta["depth_m"]
        return CapturedFrame(
            pixels=pixels,
            captured_at=captured_at,
            exposure_s=float(exposure_s),
            gain_db=gain,
            camera=self.camera_id,
            wavelength_nm=int(wavelength) if isinstance(wavelength, int) else None,
            depth_m=float(depth) if isinstance(depth, float) else None,
            extra=meta,
        )

    def close(self) -> None:
        with self._lock:
            self._closed = True

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()


class SimulatedSensors:
    """A simulated module's housing sensors: `read` returns the latest sample at the clock's time.

    Samples sit on the simulation's sensor grid (10 Hz by default); reading
    twice within one grid step returns the same sample, as a sensor with a
    data-ready register does. Reading does not wait.
    """

    def __init__(self, sim: DiveSimulation, module: str, clock: Clock) -> None:
        sim.placement(module)
        self.sim = sim
        self.module = module
        self.clock = clock

    def read(self) -> SensorSample:
        return self.sim.sensor_sample(self.module, self.sim.dive_time_s(self.clock.now()))

    def close(self) -> None:
        """Nothing to release; here for symmetry with hardware backends."""
