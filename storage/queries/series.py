"""Time series: sensors, attitude, λ_att and linearity, downsampled in the database."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from sqlalchemy import Float, cast, func, select
from sqlalchemy.orm import Session

from camcal.core.wire.sensors import SENSOR_COLUMNS as WIRE_SENSOR_COLUMNS
from storage.models import (
    AttenuationPoint,
    AttitudeSample,
    LinearityCheck,
    Module,
    SensorSample,
)


def downsampled(
    s: Session,
    model: Any,
    columns: Sequence[str],
    *,
    module: str | None,
    dive_id: int | None,
    t_from: float | None,
    t_to: float | None,
    max_points: int,
) -> dict[str, Any]:
    """A time series, averaged into at most ``max_points`` buckets when the range is long.

    The bucketing runs in the database (integer division of the time by the
    bucket width), so a whole dive of 10 Hz samples costs one aggregate query.
    Each bucket also carries the min and max of the first column, so peaks
    survive downsampling. The times are the ship's clock where the samples
    have one (``t_ship_unix_s``, `camcal.core.clockmap`), the module's
    elsewhere: the dive's one axis, on which alarms and commands lie too.
    """
    t = (
        func.coalesce(model.t_ship_unix_s, model.t_unix_s)
        if hasattr(model, "t_ship_unix_s")
        else model.t_unix_s
    )
    conds = []
    if module:
        conds.append(model.module_id == module)
    if dive_id is not None:
        conds.append(model.dive_id == dive_id)
    if t_from is not None:
        conds.append(t >= t_from)
    if t_to is not None:
        conds.append(t <= t_to)
    lo, hi, n = s.execute(select(func.min(t), func.max(t), func.count()).where(*conds)).one()
    result: dict[str, Any] = {
        "t_unix_s": [],
        **{c: [] for c in columns},
        "downsampled": False,
        "bucket_s": None,
        "n_samples": int(n or 0),
    }
    if not n:
        return result
    if n <= max_points:
        rows = s.execute(select(t, *[getattr(model, c) for c in columns]).where(*conds).order_by(t)).all()
        result["t_unix_s"] = [r[0] for r in rows]
        for i, c in enumerate(columns):
            result[c] = [r[i + 1] for r in rows]
        return result
    width = max((hi - lo) / max_points, 1e-6)
    bucket = cast(func.floor((t - lo) / width), Float).label("b")
    first = getattr(model, columns[0])
    q = (
        select(
            bucket,
            func.avg(t),
            *[func.avg(getattr(model, c)) for c in columns],
            func.min(first),
            func.max(first),
        )
        .where(*conds)
        .group_by(bucket)
        .order_by(bucket)
    )
    rows = s.execute(q).all()
    result.update(downsampled=True, bucket_s=width)
    result["t_unix_s"] = [r[1] for r in rows]
    for i, c in enumerate(columns):
        result[c] = [r[i + 2] for r in rows]
    result[f"{columns[0]}_min"] = [r[-2] for r in rows]
    result[f"{columns[0]}_max"] = [r[-1] for r in rows]
    return result


#: The sensor columns of a sample (the wire's definition, `camcal.core.wire.sensors.SENSOR_SPEC`).
SENSOR_COLUMNS = tuple(c for c in WIRE_SENSOR_COLUMNS if c != "t_unix_s")


ATTITUDE_COLUMNS = (
    "tilt_deg",
    "tilt_x_deg",
    "tilt_y_deg",
    "rotation_rate_dps",
    "heave_period_s",
    "heave_amplitude_m_s2",
)


def sensor_series(s: Session, **kw: Any) -> dict[str, Any]:
    return downsampled(s, SensorSample, SENSOR_COLUMNS, **kw)


def attitude_series(s: Session, **kw: Any) -> dict[str, Any]:
    return downsampled(s, AttitudeSample, ATTITUDE_COLUMNS, **kw)


def attenuation_series(
    s: Session, run_id: int, wavelength_nm: int | None = None, t_from: float | None = None
) -> dict[int, list[dict[str, Any]]]:
    q = select(AttenuationPoint).where(AttenuationPoint.run_id == run_id)
    if wavelength_nm is not None:
        q = q.where(AttenuationPoint.wavelength_nm == wavelength_nm)
    if t_from is not None:
        q = q.where(AttenuationPoint.t_unix_s >= t_from)
    out: dict[int, list[dict[str, Any]]] = {}
    for p in s.scalars(q.order_by(AttenuationPoint.t_unix_s)):
        out.setdefault(p.wavelength_nm, []).append(attenuation_dict(p))
    return out


def visit_keys(s: Session, run_id: int) -> set[str]:
    """The visit keys of a run's λ_att points."""
    q = select(AttenuationPoint.visit_key).where(AttenuationPoint.run_id == run_id)
    return {str(k) for k in s.scalars(q) if k is not None}


def attenuation_dict(p: AttenuationPoint) -> dict[str, Any]:
    total = None
    if p.stat_err_m is not None and p.sys_err_m is not None:
        total = math.hypot(p.stat_err_m, p.sys_err_m)
    return {
        "id": p.id,
        "run_id": p.run_id,
        "wavelength_nm": p.wavelength_nm,
        "t_unix_s": p.t_unix_s,
        "t_ship_unix_s": p.t_ship_unix_s,
        "depth_m": p.depth_m,
        "lambda_att_m": p.lambda_att_m,
        "stat_err_m": p.stat_err_m,
        "sys_err_m": p.sys_err_m,
        "total_err_m": total,
        "n_pairs": p.n_pairs,
        "n_frames": p.n_frames,
        "chi2_ndof": p.chi2_ndof,
        "window_s": p.window_s,
        "visit_key": p.visit_key,
        "t_first_unix_s": p.t_first_unix_s,
        "t_last_unix_s": p.t_last_unix_s,
        "final": p.final,
        "details": p.details,
    }


def linearity(s: Session, run_id: int, module: str | None = None) -> list[dict[str, Any]]:
    q = select(LinearityCheck).where(LinearityCheck.run_id == run_id)
    if module:
        q = q.where(LinearityCheck.module_id == module)
    return [
        {
            "module": c.module_id,
            "wavelength_nm": c.wavelength_nm,
            "sweep": c.sweep,
            "fixed_value": c.fixed_value,
            "slope": c.slope,
            "slope_err": c.slope_err,
            "intercept_gray": c.intercept_gray,
            "r2": c.r2,
            "n_used": c.n_used,
            "linear_max_gray": c.linear_max_gray,
            "knee_x": c.knee_x,
            "points": c.points,
            "updated_unix_s": c.updated_unix_s,
        }
        for c in s.scalars(
            q.order_by(LinearityCheck.module_id, LinearityCheck.wavelength_nm, LinearityCheck.sweep)
        )
    ]


def latest_sensors(s: Session, dive_id: int | None = None) -> dict[str, dict[str, Any]]:
    """Per module, the sensor sample received last (not the one of the latest time: a module's clock
    writes that, and a restarted simulation's ran behind the previous run's)."""
    out: dict[str, dict[str, Any]] = {}
    for (m,) in s.execute(select(Module.id)):
        q = select(SensorSample).where(SensorSample.module_id == m)
        if dive_id is not None:
            q = q.where(SensorSample.dive_id == dive_id)
        row = s.scalars(q.order_by(SensorSample.id.desc()).limit(1)).first()  # received last
        if row is not None:
            out[m] = {"t_unix_s": row.t_unix_s, **{c: getattr(row, c) for c in SENSOR_COLUMNS}}
    return out


def latest_attitude(s: Session, dive_id: int | None = None) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for (m,) in s.execute(select(Module.id)):
        q = select(AttitudeSample).where(AttitudeSample.module_id == m)
        if dive_id is not None:
            q = q.where(AttitudeSample.dive_id == dive_id)
        row = s.scalars(q.order_by(AttitudeSample.id.desc()).limit(1)).first()  # stored last
        if row is not None:
            out[m] = {"t_unix_s": row.t_unix_s, **{c: getattr(row, c) for c in ATTITUDE_COLUMNS}}
    return out
