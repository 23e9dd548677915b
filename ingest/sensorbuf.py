"""The newest sensor samples of each module, kept in memory for the attitude and the humidity alarm."""

from __future__ import annotations

import itertools
from collections import defaultdict, deque
from typing import Any

import numpy as np

from camcal.core.events import EventKind
from camcal.core.wire.sensorrows import rows_dicts
from ingest.alarms import AlarmEvaluator

Attitude = tuple[float, float, float, float, float, float, float]  # t, acc xyz, gyro xyz


class SensorBuffers:
    """Per module, the last 20 000 samples of time, acceleration and rotation; the newest sample is
    published (at most twice a second of the module's time) as a transient ``sensors`` event."""

    def __init__(self, alarms: AlarmEvaluator, events: Any) -> None:
        self.alarms = alarms
        self.events = events
        self.sensors: dict[str, deque[Attitude]] = defaultdict(lambda: deque(maxlen=20000))
        self.last_sensor_event: dict[str, float] = {}

    def add(self, module: str, rows: np.ndarray) -> None:
        """Samples just stored (an array of `camcal.core.wire.sensorrows.rows_array`)."""
        samples = rows_dicts(rows)
        buf = self.sensors[module]
        for s in samples:
            t = s.get("t_unix_s")
            ax, ay, az = s.get("acc_x_m_s2"), s.get("acc_y_m_s2"), s.get("acc_z_m_s2")
            if t is None or ax is None or ay is None or az is None:
                continue
            buf.append(
                (
                    t,
                    ax,
                    ay,
                    az,
                    s.get("gyro_x_dps") or 0.0,
                    s.get("gyro_y_dps") or 0.0,
                    s.get("gyro_z_dps") or 0.0,
                )
            )
            humidity = s.get("humidity_pct")
            if humidity is not None:
                self.alarms.observe_humidity(module, t, humidity)
        if samples:
            last = samples[-1]
            tlast = last.get("t_unix_s") or 0.0
            if tlast - self.last_sensor_event.get(module, -1e18) >= 0.5:
                self.last_sensor_event[module] = tlast
                self.events.transient(EventKind.SENSORS, dict(last), module=module)

    def tail(self, module: str, window_s: float) -> np.ndarray:
        """The samples of the last ``window_s`` seconds (rows in time order), without copying the rest.

        Once a second per module: converting the whole buffer (20 000 samples)
        would cost ~13 ms a module, which 100 modules on one ingest cannot afford.
        """
        buf = self.sensors[module]
        t_from = buf[-1][0] - window_s
        n = 0
        for row in reversed(buf):
            if row[0] < t_from:
                break
            n += 1
        return np.array(list(itertools.islice(reversed(buf), n))[::-1])
