"""Read-side queries for the dashboard and the API: filtered, paged, downsampled."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Float, and_, cast, func, select
from sqlalchemy.orm import Session

from storage.models import (
    Alarm,
    AnalysisRun,
    AttenuationPoint,
    AttitudeSample,
    AuditEntry,
    ChiSquareFitRecord,
    Dive,
    Event,
    Frame,
    FrameResult,
    LinearityCheck,
    Module,
    SensorSample,
)


@dataclass(frozen=True)
class FrameFilter:
    """What the frame browser can filter on (all optional)."""

    dive_id: int | None = None
    module: str | None = None
    wavelength_nm: int | None = None
    exposure_s: float | None = None
    gain_db: float | None = None
    status: str | None = None
    reason: str | None = None
    t_from: float | None = None
    t_to: float | None = None
    depth_min_m: float | None = None
    depth_max_m: float | None = None


def live_run_id(s: Session, dive_id: int) -> int | None:
    return s.scalar(select(AnalysisRun.id).where(AnalysisRun.dive_id == dive_id, AnalysisRun.kind == "live"))


def dives(s: Session, dive_id: int | None = None) -> list[dict[str, Any]]:
    """Every dive (or only ``dive_id``) with its frame count and time range, newest first."""
    counts = (
        select(
            Frame.dive_id,
            func.count(Frame.id).label("n"),
            func.min(Frame.captured_unix_s).label("t0"),
            func.max(Frame.captured_unix_s).label("t1"),
            func.max(Frame.depth_m).label("dmax"),
        )
        .group_by(Frame.dive_id)
        .subquery()
    )
    q = select(Dive, counts.c.n, counts.c.t0, counts.c.t1, counts.c.dmax).outerjoin(
        counts, counts.c.dive_id == Dive.id
    )
    if dive_id is not None:
        q = q.where(Dive.id == dive_id)
    rows = s.execute(q.order_by(Dive.id.desc())).all()
    return [
        {
            "id": d.id,
            "name": d.name,
            "started_unix_s": d.started_unix_s,
            "ended_unix_s": d.ended_unix_s,
            "notes": d.notes,
            "calibration_id": d.calibration_id,
            "n_frames": n or 0,
            "first_frame_unix_s": t0,
            "last_frame_unix_s": t1,
            "max_depth_m": dmax,
        }
        for d, n, t0, t1, dmax in rows
    ]


def frame_settings(s: Session, dive_id: int) -> dict[str, list[Any]]:
    """The distinct modules, wavelengths, exposures and gains of a dive's frames (for filter menus)."""
    out: dict[str, list[Any]] = {}
    for key, col in (
        ("modules", Frame.module_id),
        ("wavelengths_nm", Frame.wavelength_nm),
        ("exposures_s", Frame.exposure_s),
        ("gains_db", Frame.gain_db),
    ):
        q = select(col).where(Frame.dive_id == dive_id).distinct().order_by(col)
        out[key] = [v for (v,) in s.execute(q)]
    return out


def frames_page(
    s: Session, f: FrameFilter, run_id: int | None, limit: int, offset: int, order: str = "time"
) -> tuple[list[dict[str, Any]], int]:
    """One page of frames with their result in ``run_id``, and the total matching."""
    conds = []
    if f.dive_id is not None:
        conds.append(Frame.dive_id == f.dive_id)
    if f.module:
        conds.append(Frame.module_id == f.module)
    if f.wavelength_nm is not None:
        conds.append(Frame.wavelength_nm == f.wavelength_nm)
    if f.exposure_s is not None:
        conds.append(func.abs(Frame.exposure_s - f.exposure_s) < 1e-9)
    if f.gain_db is not None:
        conds.append(func.abs(Frame.gain_db - f.gain_db) < 1e-9)
    if f.t_from is not None:
        conds.append(Frame.captured_unix_s >= f.t_from)
    if f.t_to is not None:
        conds.append(Frame.captured_unix_s <= f.t_to)
    if f.depth_min_m is not None:
        conds.append(Frame.depth_m >= f.depth_min_m)
    if f.depth_max_m is not None:
        conds.append(Frame.depth_m <= f.depth_max_m)
    join = and_(FrameResult.frame_id == Frame.id, FrameResult.run_id == (run_id or -1))
    if f.status == "pending":
        conds.append(FrameResult.id.is_(None))
    elif f.status:
        conds.append(FrameResult.status == f.status)
    if f.reason:
        conds.append(FrameResult.reason == f.reason)
    base = select(Frame, FrameResult).outerjoin(FrameResult, join).where(*conds)
    total = s.scalar(select(func.count()).select_from(base.subquery())) or 0
    ordering = Frame.captured_unix_s.desc() if order == "newest" else Frame.captured_unix_s
    rows = s.execute(base.order_by(ordering, Frame.id).limit(limit).offset(offset)).all()
    return [frame_dict(fr, res) for fr, res in rows], int(total)


def frame_dict(fr: Frame, res: FrameResult | None, *, full: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": fr.id,
        "dive_id": fr.dive_id,
        "module": fr.module_id,
        "boot": fr.boot,
        "seq": fr.seq,
        "captured_unix_s": fr.captured_unix_s,
        "received_unix_s": fr.received_unix_s,
        "wavelength_nm": fr.wavelength_nm,
        "exposure_s": fr.exposure_s,
        "gain_db": fr.gain_db,
        "depth_m": fr.depth_m,
        "width_px": fr.width_px,
        "height_px": fr.height_px,
        "size_bytes": fr.size_bytes,
        "sha256": fr.sha256,
        "schedule_version": fr.schedule_version,
        "source": fr.source,
        "status": res.status if res else "pending",
        "reason": res.reason if res else None,
        "centroid_px": [res.centroid_x_px, res.centroid_y_px]
        if res and res.centroid_x_px is not None
        else None,
        "radius_px": res.radius_px if res else None,
        "i_center_gray": res.i_center_gray if res else None,
        "i_center_err_gray": res.i_center_err_gray if res else None,
        "background_gray": res.background_gray if res else None,
    }
    if full and res is not None:
        out.update(
            {
                "detail": res.detail,
                "elongation": res.elongation,
                "center_gray": res.center_gray,
                "center_err_gray": res.center_err_gray,
                "background_err_gray": res.background_err_gray,
                "fit": res.fit,
                "profile": res.profile,
                "run_id": res.run_id,
                "analysed_unix_s": res.analysed_unix_s,
            }
        )
    return out


def frame_file(s: Session, frame_id: int) -> tuple[str, int, int] | None:
    """The stored path, width and height of a frame, or None if there is no such frame."""
    row = s.execute(select(Frame.path, Frame.width_px, Frame.height_px).where(Frame.id == frame_id)).first()
    return (row[0], row[1], row[2]) if row is not None else None


def frame_with_result(
    s: Session, frame_id: int, run_id: int | None
) -> tuple[Frame, FrameResult | None] | None:
    fr = s.get(Frame, frame_id)
    if fr is None:
        return None
    rid = run_id or live_run_id(s, fr.dive_id)
    res = s.scalars(
        select(FrameResult).where(FrameResult.frame_id == frame_id, FrameResult.run_id == rid)
    ).first()
    return fr, res


def quality_counts(
    s: Session, run_id: int, module: str | None = None, since: float | None = None
) -> dict[str, dict[str, int]]:
    """Frames by status/reason per module in a run."""
    q = (
        select(Frame.module_id, FrameResult.status, FrameResult.reason, func.count())
        .join(FrameResult, FrameResult.frame_id == Frame.id)
        .where(FrameResult.run_id == run_id)
    )
    if module:
        q = q.where(Frame.module_id == module)
    if since is not None:
        q = q.where(Frame.captured_unix_s >= since)
    out: dict[str, dict[str, int]] = {}
    for mod, status, reason, n in s.execute(
        q.group_by(Frame.module_id, FrameResult.status, FrameResult.reason)
    ):
        key = "ok" if status == "ok" else (reason or "rejected")
        out.setdefault(mod, {})[key] = out.get(mod, {}).get(key, 0) + int(n)
    return out


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
    survive downsampling.
    """
    t = model.t_unix_s
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


SENSOR_COLUMNS = (
    "temperature_c",
    "humidity_pct",
    "acc_x_m_s2",
    "acc_y_m_s2",
    "acc_z_m_s2",
    "gyro_x_dps",
    "gyro_y_dps",
    "gyro_z_dps",
    "depth_m",
)
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


def attenuation_dict(p: AttenuationPoint) -> dict[str, Any]:
    total = None
    if p.stat_err_m is not None and p.sys_err_m is not None:
        total = math.hypot(p.stat_err_m, p.sys_err_m)
    return {
        "id": p.id,
        "run_id": p.run_id,
        "wavelength_nm": p.wavelength_nm,
        "t_unix_s": p.t_unix_s,
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


def alarms(s: Session, *, active: bool | None = None, limit: int = 200) -> list[dict[str, Any]]:
    q = select(Alarm)
    if active is not None:
        q = q.where(Alarm.active.is_(active))
    return [alarm_dict(a) for a in s.scalars(q.order_by(Alarm.id.desc()).limit(limit))]


def alarm_dict(a: Alarm) -> dict[str, Any]:
    return {
        "id": a.id,
        "key": a.key,
        "kind": a.kind,
        "module": a.module_id,
        "severity": a.severity,
        "message": a.message,
        "raised_unix_s": a.raised_unix_s,
        "cleared_unix_s": a.cleared_unix_s,
        "acked_unix_s": a.acked_unix_s,
        "acked_by": a.acked_by,
        "active": a.active,
    }


def modules(s: Session) -> list[dict[str, Any]]:
    return [
        {
            "id": m.id,
            "distance_m": m.distance_m,
            "last_seen_unix_s": m.last_seen_unix_s,
            "boot": m.boot,
            "software": m.software,
            "schedule": {"name": m.schedule_name, "version": m.schedule_version, "state": m.schedule_state},
        }
        for m in s.scalars(select(Module).order_by(Module.id))
    ]


def runs(s: Session, dive_id: int) -> list[dict[str, Any]]:
    return [
        {
            "id": r.id,
            "kind": r.kind,
            "label": r.label,
            "calibration": r.calibration if isinstance(r.calibration, dict) else {},
            "calibration_id": r.calibration_id,
            "software_version": r.software_version,
            "created_unix_s": r.created_unix_s,
            "status": r.status,
            "n_frames": r.n_frames,
        }
        for r in s.scalars(select(AnalysisRun).where(AnalysisRun.dive_id == dive_id).order_by(AnalysisRun.id))
    ]


def events_after(s: Session, after_id: int, limit: int) -> list[dict[str, Any]]:
    return [
        {
            "id": e.id,
            "kind": e.kind,
            "t": e.t_unix_s,
            "module": e.module_id,
            "dive_id": e.dive_id,
            "payload": e.payload,
        }
        for e in s.scalars(select(Event).where(Event.id > after_id).order_by(Event.id).limit(limit))
    ]


def timeline(s: Session, dive_id: int, max_points: int = 600) -> dict[str, Any]:
    """Depth over the dive (from the frames and the sensors), frame marks and alarms."""
    depth = downsampled(
        s,
        SensorSample,
        ("depth_m",),
        module=None,
        dive_id=dive_id,
        t_from=None,
        t_to=None,
        max_points=max_points,
    )
    frames = s.execute(
        select(Frame.captured_unix_s, Frame.depth_m, Frame.module_id, Frame.id)
        .where(Frame.dive_id == dive_id)
        .order_by(Frame.captured_unix_s)
    ).all()
    step = max(1, len(frames) // 2000)
    marks = [{"t_unix_s": t, "depth_m": d, "module": m, "id": i} for t, d, m, i in frames[::step]]
    dive = s.get(Dive, dive_id)
    t_lo = frames[0][0] if frames else (dive.started_unix_s if dive else None)
    alarm_rows = s.scalars(select(Alarm).where(Alarm.raised_unix_s >= (t_lo or 0) - 3600)).all()
    return {
        "depth": {"t_unix_s": depth["t_unix_s"], "depth_m": depth["depth_m"]},
        "frames": marks,
        "frame_step": step,
        "alarms": [alarm_dict(a) for a in alarm_rows],
    }


def audit(s: Session, limit: int = 500, offset: int = 0) -> list[dict[str, Any]]:
    return [
        {
            "id": a.id,
            "t_unix_s": a.t_unix_s,
            "actor": a.actor,
            "action": a.action,
            "target": a.target,
            "details": a.details,
        }
        for a in s.scalars(select(AuditEntry).order_by(AuditEntry.id.desc()).limit(limit).offset(offset))
    ]


def latest_frames(s: Session, dive_id: int, run_id: int | None) -> dict[str, dict[str, Any]]:
    """Per module, the newest frame of a dive that has a result (else the newest frame)."""
    out: dict[str, dict[str, Any]] = {}
    mods = [m for (m,) in s.execute(select(Frame.module_id).where(Frame.dive_id == dive_id).distinct())]
    for m in mods:
        q = (
            select(Frame, FrameResult)
            .outerjoin(
                FrameResult, and_(FrameResult.frame_id == Frame.id, FrameResult.run_id == (run_id or -1))
            )
            .where(Frame.dive_id == dive_id, Frame.module_id == m)
        )
        row = s.execute(
            q.where(FrameResult.id.is_not(None)).order_by(Frame.captured_unix_s.desc()).limit(1)
        ).first()
        row = row or s.execute(q.order_by(Frame.captured_unix_s.desc()).limit(1)).first()
        if row is not None:
            out[m] = frame_dict(*row)
    return out


def latest_sensors(s: Session, dive_id: int | None = None) -> dict[str, dict[str, Any]]:
    """Per module, its most recent sensor sample."""
    out: dict[str, dict[str, Any]] = {}
    for (m,) in s.execute(select(Module.id)):
        q = select(SensorSample).where(SensorSample.module_id == m)
        if dive_id is not None:
            q = q.where(SensorSample.dive_id == dive_id)
        row = s.scalars(q.order_by(SensorSample.t_unix_s.desc()).limit(1)).first()
        if row is not None:
            out[m] = {"t_unix_s": row.t_unix_s, **{c: getattr(row, c) for c in SENSOR_COLUMNS}}
    return out


def latest_attitude(s: Session, dive_id: int | None = None) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for (m,) in s.execute(select(Module.id)):
        q = select(AttitudeSample).where(AttitudeSample.module_id == m)
        if dive_id is not None:
            q = q.where(AttitudeSample.dive_id == dive_id)
        row = s.scalars(q.order_by(AttitudeSample.t_unix_s.desc()).limit(1)).first()
        if row is not None:
            out[m] = {"t_unix_s": row.t_unix_s, **{c: getattr(row, c) for c in ATTITUDE_COLUMNS}}
    return out


def chisq_fit_dict(r: ChiSquareFitRecord, *, full: bool = True) -> dict[str, Any]:
    out: dict[str, Any] = {
        "id": r.id,
        "dive_id": r.dive_id,
        "run_id": r.run_id,
        "calibration_id": r.calibration_id,
        "created_unix_s": r.created_unix_s,
        "software_version": r.software_version,
        "label": r.label,
        "span": r.span,
    }
    if full:
        out["result"] = r.result
    return out


def chisq_fits(s: Session, dive_id: int) -> list[dict[str, Any]]:
    """The χ² fits kept for a dive, oldest first, without their documents."""
    q = select(ChiSquareFitRecord).where(ChiSquareFitRecord.dive_id == dive_id)
    return [chisq_fit_dict(r, full=False) for r in s.scalars(q.order_by(ChiSquareFitRecord.id))]


def latest_chisq_fit(s: Session, dive_id: int, run_id: int | None = None) -> dict[str, Any] | None:
    """The newest χ² fit of a dive (of one run's calibration if given), with its document."""
    q = select(ChiSquareFitRecord).where(ChiSquareFitRecord.dive_id == dive_id)
    if run_id is not None:
        q = q.where(ChiSquareFitRecord.run_id == run_id)
    r = s.scalars(q.order_by(ChiSquareFitRecord.id.desc()).limit(1)).first()
    return chisq_fit_dict(r) if r is not None else None


def dive_record(s: Session, dive_id: int) -> dict[str, Any] | None:
    """One dive as `dives` lists it (frame count, time range, deepest depth), with its setup."""
    rows = dives(s, dive_id)
    if not rows:
        return None
    dive = s.get(Dive, dive_id)
    return {**rows[0], "setup": dive.setup if dive else {}}


def frame_outcomes(s: Session, dive_id: int, run_id: int | None) -> list[dict[str, Any]]:
    """Every frame of a dive in capture order with its outcome in a run (``pending`` without one)."""
    join = and_(FrameResult.frame_id == Frame.id, FrameResult.run_id == (run_id or -1))
    rows = s.execute(
        select(
            Frame.captured_unix_s,
            Frame.depth_m,
            Frame.module_id,
            Frame.wavelength_nm,
            FrameResult.status,
            FrameResult.reason,
        )
        .outerjoin(FrameResult, join)
        .where(Frame.dive_id == dive_id)
        .order_by(Frame.captured_unix_s, Frame.id)
    ).all()
    return [
        {
            "t_unix_s": t,
            "depth_m": d,
            "module": m,
            "wavelength_nm": wl,
            "status": status or "pending",
            "reason": reason,
        }
        for t, d, m, wl, status, reason in rows
    ]
