"""The real cameras a module drives, behind `lrm.camera.CameraBackend`.

* `lrm.cameras.aravis`: any GenICam camera (USB3 Vision, GigE Vision) through Aravis; needs
  ``camcal[camera]`` and Debian's ``gir1.2-aravis-0.8`` (imported only when used).
* `lrm.cameras.v4l2`: a UVC camera through OpenCV's V4L2 backend.

`CameraTemperature` sends a camera's own temperature (GenICam ``DeviceTemperature``) as the
module's housing temperature, for a module with no other housing sensor.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from lrm.sensors import SensorSample


class CameraTemperature:
    """A `lrm.camera.SensorBackend` of one reading: the camera's temperature at its last frame.

    The camera reads its ``DeviceTemperature`` after each frame (a register read beside the
    capture, never from this thread: a capture holds the camera for up to its exposure). A
    sample carries that value; the housing's humidity and motion stay null (no such sensor on
    this module). Before the camera's first frame, and for a camera without a temperature,
    there is no sample (None): a module started before its camera sends the temperature once
    the camera is there.
    """

    def __init__(self, camera: Any, module: str) -> None:
        self.camera = camera
        self.module = module

    def read(self) -> SensorSample | None:
        t = getattr(self.camera, "temperature_c", None)
        if t is None:
            return None
        return SensorSample(datetime.now(UTC), self.module, t, None, None, None)

    def close(self) -> None:
        """Nothing to release: the camera is the capture's."""
