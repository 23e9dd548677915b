"""Reads of dives and analysis runs: the dive list, runs, results, χ² fits, the timeline."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from sqlalchemy import and_, func, select
from sqlalchemy.orm import Session

from camcal.core.frameset import Setup, parse_setup
from camcal.core.owner import gone
from storage.base import now_unix_s
from storage.models import (
    Alarm,
    AnalysisRun,
    ChiSquareFitRecord,
    Dive,
    Frame,
    FrameResult,
    ModuleClockRecord,
    SensorSample,
)
from storage.queries.divestate import DiveRules, dive_state
from storage.queries.operations import alarm_dict
from storage.queries.series import downsampled

#: How often the process that holds a re-analysis (queued or running) says so, in seconds.
RUN_BEAT_S = 5.0
#: A queued or running re-analysis not heard of for this long was stopped with its process (the
#: server or ``camcal reanalyze`` killed, the machine down): it reads as ``interrupted``.
RUN_STALE_S = 30.0
UNFINISHED = ("queued", "running")
INTERRUPTED_NOTE = "the server or `camcal reanalyze` running it stopped before it finished: start it again"


def is_stale(heartbeat_unix_s: float | None, now_unix_s: float) -> bool:
    """Whether a queued or running re-analysis has not been heard of for `RUN_STALE_S`."""
    return heartbeat_unix_s is None or heartbeat_unix_s < now_unix_s - RUN_STALE_S


def is_orphan(r: AnalysisRun, now_unix_s: float) -> bool:
    """A re-analysis still marked queued or running whose process is gone: silent for `RUN_STALE_S`,
    or ended on this host (`camcal.core.owner.gone`)."""
    return (
        r.kind != "live"
        and r.status in UNFINISHED
        and (is_stale(r.heartbeat_unix_s, now_unix_s) or gone(r.owner))
    )


def run_status(r: AnalysisRun, now_unix_s: float) -> tuple[str, str | None]:
    """A run's status as people should read it, and a note saying what to do when it needs one."""
    if r.status == "interrupted" or is_orphan(r, now_unix_s):
        return "interrupted", INTERRUPTED_NOTE
    return r.status, None


def live_run_id(s: Session, dive_id: int) -> int | None:
    return s.scalar(select(AnalysisRun.id).where(AnalysisRun.dive_id == dive_id, AnalysisRun.kind == "live"))


def dives(s: Session, dive_id: int | None = None, rules: DiveRules | None = None) -> list[dict[str, Any]]:
    """Every dive (or only ``dive_id``) with its frame count, time range and deepest depth, newest
    first, and whether it is open or ended and why (`storage.queries.divestate`, by ``rules``)."""
    counts = (
        select(
            Frame.dive_id,
            func.count(Frame.id).label("n"),
            func.min(Frame.captured_unix_s).label("t0"),
            func.max(Frame.captured_unix_s).label("t1"),
            func.max(Frame.depth_m).label("dmax"),
            func.min(Frame.received_unix_s).label("r0"),
            func.max(Frame.received_unix_s).label("r1"),
        )
        .group_by(Frame.dive_id)
        .subquery()
    )
    q = select(Dive, counts.c.n, counts.c.t0, counts.c.t1, counts.c.dmax, counts.c.r0, counts.c.r1).outerjoin(
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
            "end_reason": d.end_reason,
            "notes": d.notes,
            "calibration_id": d.calibration_id,
            "n_frames": n or 0,
            "first_frame_unix_s": t0,
            "last_frame_unix_s": t1,
            "first_received_unix_s": r0,
            "last_received_unix_s": r1,
            "max_depth_m": dmax,
            **dive_state(s, d, rules).as_dict(),
        }
        for d, n, t0, t1, dmax, r0, r1 in rows
    ]


def newest_dive_id(s: Session) -> int | None:
    """The dive begun last (the live view's)."""
    return s.scalar(select(func.max(Dive.id)))


def last_received_unix_s(s: Session, dive_id: int) -> float | None:
    """When the ship last received a frame of the dive over the link (None: never; imports do not
    count): a recent one says an ingest is recording into it."""
    return s.scalar(
        select(func.max(Frame.received_unix_s)).where(Frame.dive_id == dive_id, Frame.source != "import")
    )


def dive_record(s: Session, dive_id: int) -> dict[str, Any] | None:
    """One dive as `dives` lists it (frame count, time range, deepest depth), with its setup."""
    rows = dives(s, dive_id)
    if not rows:
        return None
    dive = s.get(Dive, dive_id)
    return {**rows[0], "setup": dive.setup if dive else {}}


def calibration_in_force(s: Session, dive_id: int, run: dict[str, Any]) -> dict[str, Any]:
    """The setup.json values a run of the dive was analysed with (``{}``: the defaults, T-REX's).

    The run's own calibration; else the dive's own setup: the live run of an imported dive stores
    none, and its frames were analysed with the setup.json its frame set brought (the dive adopted
    it). Every reader of a run's calibration (the API's tables, the report, ``camcal fit --dive``,
    a re-analysis's start) takes it from here, so none falls back to T-REX's values alone.
    """
    dive = s.get(Dive, dive_id)
    return _in_force(run.get("calibration") or {}, dive.setup if dive is not None else {})[0]


def _in_force(own: dict[str, Any], dive_setup: dict[str, Any] | None) -> tuple[dict[str, Any], str]:
    """The setup.json values in force for a run and where they came from: ``run`` (its own
    calibration), ``dive`` (the dive's own setup: an imported frame set's) or ``defaults`` ({}:
    T-REX's)."""
    if own:
        return dict(own), "run"
    if dive_setup:
        return dict(dive_setup), "dive"
    return {}, "defaults"


def setup_in_force(s: Session, dive_id: int, run: dict[str, Any]) -> Setup:
    """`calibration_in_force` as the setup it describes (T-REX's where it is empty)."""
    cal = calibration_in_force(s, dive_id, run)
    return parse_setup(cal, f"run {run.get('id')}") if cal else Setup()


def dive_by_name(s: Session, name: str) -> Dive | None:
    return s.scalars(select(Dive).where(Dive.name == name)).first()


def runs(s: Session, dive_id: int, *, count_results: bool = True) -> list[dict[str, Any]]:
    """The dive's analysis runs, oldest first; a re-analysis whose process stopped reads as
    ``interrupted`` (with a ``note``) even before a server marks it so (`RUN_STALE_S`).

    ``setup`` is what each run was analysed with, written out whole (T-REX's defaults included).
    Without ``count_results`` no run's results are counted: ``n_frames`` is then the stored count,
    kept only for a finished re-analysis (what picks a run needs no count of a whole dive).
    """
    now = now_unix_s()
    out = []
    rows = s.scalars(select(AnalysisRun).where(AnalysisRun.dive_id == dive_id).order_by(AnalysisRun.id)).all()
    # A re-analysis under way (or stopped) counts the results it has stored so far (its progress);
    # the live run, never finished, the results the ingest and imports have stored.
    counting = [r.id for r in rows if r.kind == "live" or r.status != "done"] if count_results else []
    stored = dict(
        s.execute(
            select(FrameResult.run_id, func.count())
            .where(FrameResult.run_id.in_(counting))
            .group_by(FrameResult.run_id)
        ).all()
        if counting
        else []
    )
    dive = s.get(Dive, dive_id)
    dive_setup = dive.setup if dive is not None and isinstance(dive.setup, dict) else {}
    defaults: dict[str, Any] | None = None
    for r in rows:
        status, note = run_status(r, now)
        own = r.calibration if isinstance(r.calibration, dict) else {}
        setup, setup_from = _in_force(own, dive_setup)
        if setup_from == "defaults":
            defaults = defaults or Setup().to_json()
            setup = defaults
        out.append(
            {
                "id": r.id,
                "kind": r.kind,
                "label": r.label,
                "calibration": own,
                "setup": setup,
                "setup_from": setup_from,
                "calibration_id": r.calibration_id,
                "software_version": r.software_version,
                "created_unix_s": r.created_unix_s,
                "status": status,
                "n_frames": stored.get(r.id, 0) if r.id in counting else r.n_frames,
                "note": note,
            }
        )
    return out


class RunLookupError(LookupError):
    """No such run of the dive, or the dive has none yet (the message says which)."""


def dive_and_run(s: Session, dive_id: int | None, run_id: int | None) -> tuple[int | None, int | None]:
    """The dive asked for (else the run's, else the newest; None without any) and the run asked for
    (else that dive's live run, None without one).

    Raises `RunLookupError` for a dive or run that does not exist, or a run of another dive: a
    filter naming one would otherwise answer as if nothing matched.
    """
    run = s.get(AnalysisRun, run_id) if run_id is not None else None
    if run_id is not None and run is None:
        raise RunLookupError(f"no analysis run {run_id}")
    if dive_id is not None:
        if s.get(Dive, dive_id) is None:
            raise RunLookupError(f"no dive {dive_id}")
    elif run is not None:
        dive_id = run.dive_id
    else:
        newest = s.scalar(select(func.max(Dive.id)))
        if newest is None:
            return None, None
        dive_id = int(newest)
    if run is None:
        return dive_id, live_run_id(s, dive_id)
    if run.dive_id != dive_id:
        raise RunLookupError(f"run {run_id} is of dive {run.dive_id}, not of dive {dive_id}")
    return dive_id, run.id


def chosen_run(s: Session, dive_id: int, run_id: int | None = None) -> dict[str, Any]:
    """Run ``run_id`` of the dive, or by default its live run, else its newest (as `runs` gives them,
    its results not counted).

    Raises `RunLookupError` when the dive has no run or no run ``run_id``.
    """
    by_id = {r["id"]: r for r in runs(s, dive_id, count_results=False)}
    if not by_id:
        raise RunLookupError(f"dive {dive_id} has no analysis run yet (nothing was ingested or imported)")
    if run_id is None:
        live = [r for r in by_id.values() if r["kind"] == "live"]
        return live[0] if live else by_id[max(by_id)]
    if run_id not in by_id:
        have = ", ".join(map(str, sorted(by_id)))
        raise RunLookupError(f"no run {run_id} in dive {dive_id} (runs: {have})")
    return by_id[run_id]


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


def ship_time(model: Any) -> Any:
    """A table's module time on the ship's clock where it has one (`camcal.core.clockmap`)."""
    if model is Frame:  # (always set: the capture time stands where no mapping is known)
        return Frame.captured_ship_unix_s
    return func.coalesce(model.t_ship_unix_s, model.t_unix_s)


def timeline(s: Session, dive_id: int, max_points: int = 600) -> dict[str, Any]:
    """Depth over the dive (from the frames and the sensors), frame marks, alarms and each module's
    clock, all on the ship's clock: the dive's one axis (the modules' times mapped onto it, at the
    handshake and every heartbeat: `camcal.core.clockmap`), so that what happened is drawn in the
    order it happened. A frame mark keeps its module's time as ``captured_unix_s``."""
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
    t_ship = ship_time(Frame)
    frames = s.execute(
        select(t_ship, Frame.depth_m, Frame.module_id, Frame.id, Frame.captured_unix_s)
        .where(Frame.dive_id == dive_id)
        .order_by(t_ship, Frame.id)
    ).all()
    step = max(1, len(frames) // 2000)
    marks = [
        {"t_unix_s": c if t is None else t, "depth_m": d, "module": m, "id": i, "captured_unix_s": c}
        for t, d, m, i, c in frames[::step]
    ]
    # Each module's own depth: the two hang ~20 m apart, and one series of both zigzags between them.
    modules = sorted({m for _, _, m, _, _ in frames})
    by_module = {}
    for m in modules:
        d = downsampled(
            s,
            SensorSample,
            ("depth_m",),
            module=m,
            dive_id=dive_id,
            t_from=None,
            t_to=None,
            max_points=max(50, max_points // max(1, len(modules))),
        )
        if d["t_unix_s"]:
            by_module[m] = {"t_unix_s": d["t_unix_s"], "depth_m": d["depth_m"]}
    dive = s.get(Dive, dive_id)
    times = [t for t, *_ in frames if t is not None]  # (a row written by hand may have none)
    t_lo = times[0] if times else (dive.started_unix_s if dive else None)
    t_hi = max(times[-1] if times else 0.0, (dive.ended_unix_s or now_unix_s()) if dive else 0.0)
    alarm_rows = s.scalars(  # the dive's time (its frames', or the ship's while it is open), an hour around
        select(Alarm).where(Alarm.raised_unix_s.between((t_lo or 0) - 3600, t_hi + 3600))
    ).all()
    return {
        "depth": {"t_unix_s": depth["t_unix_s"], "depth_m": depth["depth_m"]},
        "depth_by_module": by_module,
        "frames": marks,
        "frame_step": step,
        "alarms": [alarm_dict(a) for a in alarm_rows],
        "clocks": module_clocks(s, dive_id),
    }


def module_clocks(s: Session, dive_id: int) -> list[dict[str, Any]]:
    """Each module's clock of each boot in the dive, as the ship mapped it onto its own: the rate
    (1: a real clock; 10: a simulation at 10x), the anchor and the newest offset measured."""
    rows = s.scalars(
        select(ModuleClockRecord)
        .where(ModuleClockRecord.dive_id == dive_id)
        .order_by(ModuleClockRecord.module_id, ModuleClockRecord.first_unix_s)
    )
    return [
        {
            "module": c.module_id,
            "boot": c.boot,
            "rate": c.rate,
            "module_at_unix_s": c.module_at_unix_s,
            "real_at_unix_s": c.real_at_unix_s,
            "offset_s": c.offset_s,
            "n_readings": c.n_readings,
            "first_unix_s": c.first_unix_s,
            "updated_unix_s": c.updated_unix_s,
        }
        for c in rows
    ]


def frame_outcomes(s: Session, dive_id: int, run_id: int | None) -> list[dict[str, Any]]:
    """Every frame of a dive in capture order with its outcome in a run (``pending`` without one);
    ``t_unix_s`` on the ship's clock (`ship_time`)."""
    join = and_(FrameResult.frame_id == Frame.id, FrameResult.run_id == (run_id or -1))
    t = ship_time(Frame)
    rows = s.execute(
        select(
            t,
            Frame.depth_m,
            Frame.module_id,
            Frame.wavelength_nm,
            FrameResult.status,
            FrameResult.reason,
        )
        .outerjoin(FrameResult, join)
        .where(Frame.dive_id == dive_id)
        .order_by(t, Frame.id)
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


def result_rows(s: Session, run_id: int, dive_id: int) -> list[dict[str, Any]]:
    """Frames of a dive joined with their result in a run, in capture order."""
    rows = s.execute(_result_rows_query(run_id, dive_id).order_by(Frame.captured_unix_s, Frame.id)).all()
    return [dict(zip(_RESULT_KEYS, r, strict=True)) for r in rows]


def newest_result_rows(s: Session, run_id: int, dive_id: int, n: int) -> list[dict[str, Any]]:
    """`result_rows` of the ``n`` frames received last (the store numbers frames as they arrive: not
    the latest capture times, which a module's clock writes), in the order they arrived."""
    q = _result_rows_query(run_id, dive_id).order_by(Frame.id.desc()).limit(n)
    return [dict(zip(_RESULT_KEYS, r, strict=True)) for r in reversed(s.execute(q).all())]


_RESULT_KEYS = (
    "frame_id",
    "module",
    "wavelength_nm",
    "exposure_s",
    "gain_db",
    "captured_unix_s",
    "captured_ship_unix_s",
    "depth_m",
    "path",
    "status",
    "center_gray",
    "i_center_gray",
    "i_center_err_gray",
)


def _result_rows_query(run_id: int, dive_id: int) -> Any:
    return (
        select(
            Frame.id,
            Frame.module_id,
            Frame.wavelength_nm,
            Frame.exposure_s,
            Frame.gain_db,
            Frame.captured_unix_s,
            Frame.captured_ship_unix_s,
            Frame.depth_m,
            Frame.path,
            FrameResult.status,
            FrameResult.center_gray,
            FrameResult.i_center_gray,
            FrameResult.i_center_err_gray,
        )
        .join(FrameResult, (FrameResult.frame_id == Frame.id) & (FrameResult.run_id == run_id))
        .where(Frame.dive_id == dive_id)
    )


def frames_without_result(
    s: Session, dive_id: int, run_id: int, limit: int = 100_000, modules: Sequence[str] = ()
) -> list[Frame]:
    """Stored frames of a dive that the run has not analysed (e.g. after a crash), of ``modules``
    if given (an ingest recovers only the frames of the modules it serves)."""
    done = select(FrameResult.frame_id).where(FrameResult.run_id == run_id)
    q = select(Frame).where(Frame.dive_id == dive_id, Frame.id.not_in(done))
    if modules:
        q = q.where(Frame.module_id.in_(list(modules)))
    return list(s.scalars(q.order_by(Frame.id).limit(limit)))


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
