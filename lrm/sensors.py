"""Housing sensors of a light receiver module: one sample, and tilt from gravity.

Each LRM's Raspberry Pi reads a temperature + humidity sensor inside the
housing and an accelerometer + gyroscope (paper, section 2 and appendix A).
A `SensorSample` is what one reading of all of them looks like, whether it
comes from the hardware or from `lrm.dive.DiveSimulation`.

Axes: the module's own frame, z up along the module's axis (the cable), x and
y across it. A module hanging still and exactly vertical reads
``acc_m_s2 = (0, 0, +g)``: an accelerometer measures the specific force, the
reaction to gravity, which points up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime

import numpy as np


def _triple(name: str, value: tuple[float, float, float]) -> tuple[float, float, float]:
    if len(value) != 3:
        raise ValueError(f"{name} must have 3 components (x, y, z), got {len(value)}")
    return (float(value[0]), float(value[1]), float(value[2]))


@dataclass(frozen=True)
class SensorSample:
    """One reading of a module's housing sensors.

    Attributes
    ----------
    t
        When the sample was taken, timezone-aware UTC.
    module
        The module's id (``"A"``, ``"B"``).
    temperature_c
        Air temperature inside the housing (None: not measured).
    humidity_pct
        Relative humidity inside the housing; a rise means water is getting in (None: no
        humidity sensor, e.g. a module whose only sensor is its camera's temperature).
    acc_m_s2
        Specific force in the module frame (z up along the module axis; None: no accelerometer).
    gyro_dps
        Rotation rates about the module's x, y, z axes, degrees per second (None: no gyroscope).
    depth_m
        Depth of the module, if known (the simulator knows it; on the real
        module it comes from the ship's winch log or a pressure sensor).
    pressure_dbar
        Water pressure (gauge, decibar) if a pressure sensor is fitted.
    """

    t: datetime
    module: str
    temperature_c: float | None
    humidity_pct: float | None
    acc_m_s2: tuple[float, float, float] | None
    gyro_dps: tuple[float, float, float] | None
    depth_m: float | None = None
    pressure_dbar: float | None = None

    def __post_init__(self) -> None:
        if self.t.tzinfo is None or self.t.utcoffset() is None:
            raise ValueError(f"t must be timezone-aware UTC, got naive {self.t.isoformat()}")
        if self.acc_m_s2 is not None:
            object.__setattr__(self, "acc_m_s2", _triple("acc_m_s2", self.acc_m_s2))
        if self.gyro_dps is not None:
            object.__setattr__(self, "gyro_dps", _triple("gyro_dps", self.gyro_dps))

    @property
    def tilt_deg(self) -> float:
        """Tilt of the module axis from the vertical, from the accelerometer."""
        if self.acc_m_s2 is None:
            raise ValueError(f"module {self.module}: no accelerometer in this sample, no tilt")
        return tilt_from_acceleration_deg(self.acc_m_s2)[2]

    def to_dict(self) -> dict[str, object]:
        """Plain JSON-ready values; the time as ISO-8601 UTC with a ``Z``."""
        return {
            "t": self.t.astimezone(UTC).isoformat().replace("+00:00", "Z"),
            "module": self.module,
            "temperature_c": self.temperature_c,
            "humidity_pct": self.humidity_pct,
            "acc_m_s2": list(self.acc_m_s2) if self.acc_m_s2 is not None else None,
            "gyro_dps": list(self.gyro_dps) if self.gyro_dps is not None else None,
            "depth_m": self.depth_m,
            "pressure_dbar": self.pressure_dbar,
        }


def tilt_from_acceleration_deg(acc_m_s2: tuple[float, float, float]) -> tuple[float, float, float]:
    """Tilt angles of a still module from its accelerometer (appendix A of the paper).

    At rest the accelerometer sees only gravity's reaction, so its direction in
    the module frame is the vertical. Returns ``(tilt_x, tilt_y, tilt)`` in
    degrees: ``atan2(a_x, a_z)``, ``atan2(a_y, a_z)`` (the inclination seen in
    the x-z and y-z planes) and the total angle between the module axis and
    the vertical, ``atan2(hypot(a_x, a_y), a_z)``. Accelerations along the
    axis (the ship's heave) change the magnitude but not these angles;
    sideways accelerations (sway) bias them slightly, so average over a few
    seconds for a steady value.
    """
    ax, ay, az = _triple("acc_m_s2", acc_m_s2)
    return (
        math.degrees(math.atan2(ax, az)),
        math.degrees(math.atan2(ay, az)),
        math.degrees(math.atan2(math.hypot(ax, ay), az)),
    )


def tilt_series_deg(acc_m_s2: np.ndarray) -> np.ndarray:
    """`tilt_from_acceleration_deg` over an ``(n, 3)`` array: an ``(n, 3)`` array of angles."""
    acc = np.asarray(acc_m_s2, dtype=np.float64)
    if acc.ndim != 2 or acc.shape[1] != 3:
        raise ValueError(f"acc_m_s2 must have shape (n, 3), got {acc.shape}")
    ax, ay, az = acc[:, 0], acc[:, 1], acc[:, 2]
    return np.degrees(
        np.stack([np.arctan2(ax, az), np.arctan2(ay, az), np.arctan2(np.hypot(ax, ay), az)], axis=1)
    )
