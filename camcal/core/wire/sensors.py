"""The sensor columns of protocol version 1: one definition for the module, the ship and the store.

A ``sensors`` payload is a JSON array of rows, each an array of numbers or
``null`` in the order of the header's ``columns``. ``t_unix_s`` is
required and never null; every other column may be left out or be null.
Unknown column names are ignored (a later version may add sensors). A value
outside its column's range cannot be a real reading: the whole message is
refused as ``invalid_field``, naming the row and the column.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from camcal.core.wire.limits import TIME_MAX_UNIX_S, TIME_MIN_UNIX_S


@dataclass(frozen=True)
class SensorColumn:
    name: str
    unit: str
    meaning: str
    lo: float
    hi: float


SENSOR_SPEC: tuple[SensorColumn, ...] = (
    SensorColumn(
        "t_unix_s", "s", "time of the sample, Unix seconds (UTC), required", TIME_MIN_UNIX_S, TIME_MAX_UNIX_S
    ),
    SensorColumn("temperature_c", "°C", "temperature inside the housing", -80.0, 200.0),
    SensorColumn("humidity_pct", "%", "relative humidity inside the housing", -10.0, 110.0),
    SensorColumn("acc_x_m_s2", "m/s²", "acceleration along x (module frame)", -2000.0, 2000.0),
    SensorColumn("acc_y_m_s2", "m/s²", "acceleration along y", -2000.0, 2000.0),
    SensorColumn(
        "acc_z_m_s2", "m/s²", "acceleration along z (the module's axis, up; +9.81 at rest)", -2000.0, 2000.0
    ),
    SensorColumn("gyro_x_dps", "°/s", "rotation rate about x", -20000.0, 20000.0),
    SensorColumn("gyro_y_dps", "°/s", "rotation rate about y", -20000.0, 20000.0),
    SensorColumn("gyro_z_dps", "°/s", "rotation rate about z", -20000.0, 20000.0),
    SensorColumn("depth_m", "m", "depth below the surface (pressure sensor)", -1000.0, 12000.0),
)
#: Column names in the order modules send them.
SENSOR_COLUMNS: tuple[str, ...] = tuple(c.name for c in SENSOR_SPEC)
_BY_NAME = {c.name: c for c in SENSOR_SPEC}


def check_columns(columns: tuple[str, ...]) -> str | None:
    """What is wrong with a header's ``columns``, or None."""
    if len(set(columns)) != len(columns):
        return "columns: a name appears twice"
    if "t_unix_s" not in columns:
        return "columns: t_unix_s is required"
    return None


def check_rows(
    columns: tuple[str, ...], rows: Any, count: int, *, first_row: int = 0
) -> list[dict[str, float | None]]:
    """The rows of a payload as dicts of the known columns (all of them, missing ones None).

    Raises ``ValueError`` naming the first row and column that is wrong (``first_row``: the number
    of the first of ``rows`` in the whole payload, when they are a part of it).
    """
    if not isinstance(rows, list) or len(rows) != count:
        raise ValueError(f"payload must be a list of {count} rows")
    width = len(columns)
    known = [(i, _BY_NAME[name]) for i, name in enumerate(columns) if name in _BY_NAME]
    out = []
    for r, row in enumerate(rows, start=first_row):
        if not isinstance(row, list) or len(row) != width:
            raise ValueError(f"row {r}: must be a list of {width} values")
        sample: dict[str, float | None] = dict.fromkeys(SENSOR_COLUMNS)
        for i, col in known:
            v = row[i]
            if v is None:
                if col.name == "t_unix_s":
                    raise ValueError(f"row {r}: t_unix_s must not be null")
                continue
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ValueError(f"row {r}: {col.name} must be a number or null")
            v = float(v)
            if not (math.isfinite(v) and col.lo <= v <= col.hi):
                unset = (
                    " (before 2000: the module's clock is not set)"
                    if col.name == "t_unix_s" and v < col.lo
                    else ""
                )
                raise ValueError(
                    f"row {r}: {col.name} = {v:g} outside {col.lo:g} .. {col.hi:g} {col.unit}{unset}"
                )
            sample[col.name] = v
        for i, v in enumerate(row):  # unknown columns: ignored, but still numbers or null
            if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)):
                raise ValueError(f"row {r}: {columns[i]} must be a number or null")
        out.append(sample)
    return out
