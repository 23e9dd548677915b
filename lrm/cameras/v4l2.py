"""A real camera on Linux through OpenCV's V4L2 backend (UVC and other V4L2 drivers).

Industrial cameras (USB3 Vision, GigE Vision) speak GenICam instead: `lrm.cameras.aravis`.
"""

from __future__ import annotations

import logging
import math
import threading
from collections.abc import Callable
from datetime import UTC
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, Self

import cv2
import numpy as np

from lrm.camera import (
    CameraClosed,
    CameraError,
    CameraUnavailable,
    CapturedFrame,
    CaptureFailed,
    check_setting,
)
from lrm.clock import Clock, SystemClock

log = logging.getLogger(__name__)


#: V4L2's ``exposure_time_absolute`` control counts in units of 100 µs.
V4L2_EXPOSURE_UNIT_S = 1e-4
#: ``CAP_PROP_AUTO_EXPOSURE`` value for manual exposure with OpenCV's V4L2 backend
#: (V4L2_EXPOSURE_MANUAL; 3 is aperture priority, i.e. automatic).
V4L2_MANUAL_EXPOSURE = 1.0


def exposure_to_device(exposure_s: float, unit_s: float = V4L2_EXPOSURE_UNIT_S) -> int:
    """The integer exposure control value for ``exposure_s`` (at least 1 unit)."""
    if not (exposure_s > 0 and math.isfinite(exposure_s)):
        raise ValueError(f"exposure_s must be > 0, got {exposure_s}")
    if not unit_s > 0:
        raise ValueError(f"unit_s must be > 0, got {unit_s}")
    return max(1, round(exposure_s / unit_s))


def exposure_from_device(value: float, unit_s: float = V4L2_EXPOSURE_UNIT_S) -> float:
    """Seconds for an exposure control value."""
    return float(value) * unit_s


def gain_to_device(gain_db: float, units_per_db: float = 1.0, offset: float = 0.0) -> int:
    """The integer gain control value for ``gain_db``: ``offset + gain_db * units_per_db``."""
    if not units_per_db > 0:
        raise ValueError(f"units_per_db must be > 0, got {units_per_db}")
    return round(offset + gain_db * units_per_db)


def gain_from_device(value: float, units_per_db: float = 1.0, offset: float = 0.0) -> float:
    """Decibels for a gain control value."""
    return (float(value) - offset) / units_per_db


def to_mono8(frame: np.ndarray, name: str = "frame") -> np.ndarray:
    """A 2-D ``uint8`` frame from what OpenCV delivered: gray as is, BGR(A) converted to gray."""
    if frame.dtype != np.uint8:
        raise CaptureFailed(f"{name} is not 8-bit: dtype {frame.dtype}; set the camera to an 8-bit format")
    if frame.ndim == 2:
        return frame
    if frame.ndim == 3 and frame.shape[2] == 1:
        return frame[:, :, 0]
    if frame.ndim == 3 and frame.shape[2] == 3:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    if frame.ndim == 3 and frame.shape[2] == 4:
        return cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY)
    raise CaptureFailed(f"{name} has an unexpected shape {frame.shape}; expected (h, w) or (h, w, 3)")


class VideoCaptureLike(Protocol):
    """The part of `cv2.VideoCapture` the V4L2 backend uses (tests pass a fake)."""

    def isOpened(self) -> bool: ...

    def set(self, prop: int, value: float) -> bool: ...

    def get(self, prop: int) -> float: ...

    def read(self) -> tuple[bool, np.ndarray | None]: ...

    def release(self) -> None: ...


def _device_path(device: int | str) -> str:
    return f"/dev/video{device}" if isinstance(device, int) else str(device)


class V4L2Camera:
    """A real camera on Linux through OpenCV's V4L2 backend.

    **Not exercised on hardware here**: the development machine has no camera;
    the tests cover the error path, the unit conversions and the control flow
    against a fake `cv2.VideoCapture`. Check the controls of the actual camera
    with ``v4l2-ctl -d /dev/videoN --list-ctrls`` before a deployment.

    Exposure and gain are set manually: ``CAP_PROP_AUTO_EXPOSURE`` to manual
    (``manual_exposure_value``, 1 for V4L2), ``CAP_PROP_EXPOSURE`` in units of
    ``exposure_unit_s`` (V4L2's ``exposure_time_absolute``: 100 µs) and
    ``CAP_PROP_GAIN`` as ``gain_offset + gain_db * gain_units_per_db`` (gain
    units are driver-specific: a driver in 0.1 dB steps wants 10). Frames are
    asked for as 8-bit gray (``GREY`` fourcc, RGB conversion off); a camera
    that only delivers colour is converted to gray.

    V4L2 queues frames: after a change of setting the next ``settle_frames``
    frames, exposed with the old setting, are read and dropped.

    Parameters
    ----------
    device
        Index (``0`` for ``/dev/video0``) or device path.
    camera_id
        The module's id, written into every frame.
    clock
        Gives ``captured_at``; the real clock by default.
    open_capture
        Opens the device, ``(device, api) -> VideoCaptureLike``; default
        `cv2.VideoCapture`. Tests pass a fake.

    Raises
    ------
    CameraUnavailable
        When the device cannot be opened; the message names it and what to check.
    """

    def __init__(
        self,
        device: int | str = 0,
        camera_id: str = "A",
        *,
        clock: Clock | None = None,
        exposure_range_s: tuple[float, float] = (1e-4, 1.0),
        gain_range_db: tuple[float, float] = (0.0, 24.0),
        exposure_unit_s: float = V4L2_EXPOSURE_UNIT_S,
        gain_units_per_db: float = 1.0,
        gain_offset: float = 0.0,
        manual_exposure_value: float = V4L2_MANUAL_EXPOSURE,
        settle_frames: int = 1,
        open_capture: Callable[[int | str, int], VideoCaptureLike] | None = None,
    ) -> None:
        if settle_frames < 0:
            raise ValueError(f"settle_frames must be >= 0, got {settle_frames}")
        if not gain_units_per_db > 0:
            raise ValueError(f"gain_units_per_db must be > 0, got {gain_units_per_db}")
        self.camera_id = camera_id
        self.device = device
        self.device_path = _device_path(device)
        self.clock: Clock = clock or SystemClock()
        self.exposure_range_s = exposure_range_s
        self.gain_range_db = gain_range_db
        self.gain_step_db = 1.0 / gain_units_per_db
        self.exposure_unit_s = exposure_unit_s
        self.gain_units_per_db = gain_units_per_db
        self.gain_offset = gain_offset
        self.settle_frames = settle_frames
        self._lock = threading.Lock()
        self._setting: tuple[int, int] | None = None

        hint = (
            "check that the camera is plugged in and powered, that the device exists "
            "(ls /dev/video*; v4l2-ctl --list-devices) and that this user may open it (group 'video')"
        )
        if open_capture is None and isinstance(device, str) and not Path(device).exists():
            raise CameraUnavailable(f"camera {camera_id}: V4L2 device {device} does not exist; {hint}")
        opener: Any = open_capture or cv2.VideoCapture
        try:
            cap = opener(device, cv2.CAP_V4L2)
        except cv2.error as exc:
            raise CameraUnavailable(
                f"camera {camera_id}: opening {self.device_path} failed ({exc}); {hint}"
            ) from exc
        if not cap.isOpened():
            cap.release()
            raise CameraUnavailable(
                f"camera {camera_id}: no V4L2 camera could be opened at {self.device_path}; {hint}"
            )
        self._cap: VideoCaptureLike | None = cap
        self._configure(cap, manual_exposure_value)

    def _configure(self, cap: VideoCaptureLike, manual_exposure_value: float) -> None:
        """Ask for 8-bit gray frames, a one-frame queue and manual exposure."""
        requests = [
            (cv2.CAP_PROP_FOURCC, float(cv2.VideoWriter.fourcc(*"GREY")), "8-bit gray format (GREY)"),
            (cv2.CAP_PROP_CONVERT_RGB, 0.0, "raw frames (no RGB conversion)"),
            (cv2.CAP_PROP_BUFFERSIZE, 1.0, "a one-frame queue"),
            (cv2.CAP_PROP_AUTO_EXPOSURE, manual_exposure_value, "manual exposure"),
        ]
        for prop, value, what in requests:
            if not cap.set(prop, value):
                log.warning("camera %s (%s) refused %s", self.camera_id, self.device_path, what)

    def _apply(self, cap: VideoCaptureLike, exposure_s: float, gain_db: float) -> tuple[int, int]:
        exp_value = exposure_to_device(exposure_s, self.exposure_unit_s)
        gain_value = gain_to_device(gain_db, self.gain_units_per_db, self.gain_offset)
        if self._setting == (exp_value, gain_value):
            return exp_value, gain_value
        if not cap.set(cv2.CAP_PROP_EXPOSURE, float(exp_value)):
            raise CameraError(
                f"camera {self.camera_id} ({self.device_path}) refused exposure {exp_value} "
                f"x {self.exposure_unit_s} s; is manual exposure supported?"
            )
        if not cap.set(cv2.CAP_PROP_GAIN, float(gain_value)):
            raise CameraError(f"camera {self.camera_id} ({self.device_path}) refused gain {gain_value}")
        for _ in range(self.settle_frames):
            cap.read()  # exposed with the previous setting
        self._setting = (exp_value, gain_value)
        return exp_value, gain_value

    def capture(self, exposure_s: float, gain_db: float) -> CapturedFrame:
        check_setting(exposure_s, gain_db, self.exposure_range_s, self.gain_range_db)
        with self._lock:
            cap = self._cap
            if cap is None:
                raise CameraClosed(f"camera {self.camera_id} ({self.device_path}) is closed")
            exp_value, gain_value = self._apply(cap, exposure_s, gain_db)
            captured_at = self.clock.now()
            ok, frame = cap.read()
            if not ok or frame is None:
                raise CaptureFailed(
                    f"camera {self.camera_id} ({self.device_path}) delivered no frame; "
                    "check the cable and that no other process holds the camera"
                )
            pixels = to_mono8(np.asarray(frame), name=f"frame from camera {self.camera_id}")
            # Report what the driver says it applied (it may clamp), if it says anything.
            exp_read = cap.get(cv2.CAP_PROP_EXPOSURE)
            gain_read = cap.get(cv2.CAP_PROP_GAIN)
        applied_exp = exp_read if exp_read > 0 else exp_value
        applied_gain = gain_read if gain_read >= 0 else gain_value
        return CapturedFrame(
            pixels=np.ascontiguousarray(pixels),
            captured_at=captured_at.astimezone(UTC),
            exposure_s=exposure_from_device(applied_exp, self.exposure_unit_s),
            gain_db=gain_from_device(applied_gain, self.gain_units_per_db, self.gain_offset),
            camera=self.camera_id,
            extra={
                "device": self.device_path,
                "exposure_device_value": float(applied_exp),
                "gain_device_value": float(applied_gain),
                "requested_exposure_s": float(exposure_s),
                "requested_gain_db": float(gain_db),
            },
        )

    def close(self) -> None:
        with self._lock:
            if self._cap is not None:
                self._cap.release()
                self._cap = None

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
