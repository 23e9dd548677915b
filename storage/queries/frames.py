"""Reads of frames and their results: the frame browser's page, one frame, where frames are."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from sqlalchemy import and_, func, select, tuple_
from sqlalchemy.orm import Session

from storage.models import (
    Dive,
    Frame,
    FrameResult,
)
from storage.queries.runs import live_run_id


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
    # Times are the ship's clock (the dive's one axis, as on the timeline): `captured_ship_unix_s`.
    if f.t_from is not None:
        conds.append(Frame.captured_ship_unix_s >= f.t_from)
    if f.t_to is not None:
        conds.append(Frame.captured_ship_unix_s <= f.t_to)
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
    taken = Frame.captured_ship_unix_s
    ordering = taken.desc() if order == "newest" else taken
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
        # on the ship's clock (the module's mapped onto it, `camcal.core.clockmap`)
        "captured_ship_unix_s": fr.captured_ship_unix_s,
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
    """Frames by status/reason per module in a run (``since``: of the frames received since then)."""
    q = (
        select(Frame.module_id, FrameResult.status, FrameResult.reason, func.count())
        .join(FrameResult, FrameResult.frame_id == Frame.id)
        .where(FrameResult.run_id == run_id)
    )
    if module:
        q = q.where(Frame.module_id == module)
    if since is not None:
        q = q.where(Frame.received_unix_s >= since)
    out: dict[str, dict[str, int]] = {}
    for mod, status, reason, n in s.execute(
        q.group_by(Frame.module_id, FrameResult.status, FrameResult.reason)
    ):
        key = "ok" if status == "ok" else (reason or "rejected")
        out.setdefault(mod, {})[key] = out.get(mod, {}).get(key, 0) + int(n)
    return out


def saturated_by_setting(s: Session, run_id: int) -> dict[str, dict[tuple[int, float, float], int]]:
    """Per module, the frames of a run rejected as saturated, counted by setting (wavelength,
    exposure, gain): the live cards tell those the schedule saturates by design from the others."""
    q = (
        select(Frame.module_id, Frame.wavelength_nm, Frame.exposure_s, Frame.gain_db, func.count())
        .join(FrameResult, FrameResult.frame_id == Frame.id)
        .where(FrameResult.run_id == run_id, FrameResult.status != "ok", FrameResult.reason == "saturated")
        .group_by(Frame.module_id, Frame.wavelength_nm, Frame.exposure_s, Frame.gain_db)
    )
    out: dict[str, dict[tuple[int, float, float], int]] = {}
    for mod, wl, exp, gain, n in s.execute(q):
        out.setdefault(mod, {})[(int(wl), float(exp), float(gain))] = int(n)
    return out


def latest_frames(s: Session, dive_id: int, run_id: int | None) -> dict[str, dict[str, Any]]:
    """Per module, the frame of a dive received last that has a result (else the one received last).

    Latest means received last (the store numbers frames as they arrive), never the largest capture
    time: a module's clock decides that, and a simulated dive run before this one (its clock running
    ahead, 10x) or a clock set wrong would keep an old frame "latest" while new ones arrive.
    """
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
        row = s.execute(q.where(FrameResult.id.is_not(None)).order_by(Frame.id.desc()).limit(1)).first()
        row = row or s.execute(q.order_by(Frame.id.desc()).limit(1)).first()
        if row is not None:
            out[m] = frame_dict(*row)
    return out


#: Whether a module's frame at a setting (wavelength, exposure, gain) is saturated by design.
ByDesign = Callable[[str, int, float, float], bool]


def recent_outcomes(
    s: Session, dive_id: int, run_id: int, n: int = 40, by_design: ByDesign | None = None
) -> dict[str, list[str]]:
    """Per module, the outcomes in a run of its ``n`` frames received last that were analysed, in the
    order they arrived: ``ok`` or the reason the frame was rejected (the live cards' strip of latest
    frames; latest as in `latest_frames`); ``saturated_by_design`` for a saturated frame at a
    setting ``by_design`` names."""
    out: dict[str, list[str]] = {}
    mods = [m for (m,) in s.execute(select(Frame.module_id).where(Frame.dive_id == dive_id).distinct())]
    for m in mods:
        rows = s.execute(
            select(
                FrameResult.status, FrameResult.reason, Frame.wavelength_nm, Frame.exposure_s, Frame.gain_db
            )
            .join(Frame, FrameResult.frame_id == Frame.id)
            .where(Frame.dive_id == dive_id, Frame.module_id == m, FrameResult.run_id == run_id)
            .order_by(Frame.id.desc())
            .limit(n)
        ).all()
        keys = []
        for st, reason, wl, exp, gain in reversed(rows):
            key = "ok" if st == "ok" else (reason or "rejected")
            if (
                key == "saturated"
                and by_design is not None
                and by_design(m, int(wl), float(exp), float(gain))
            ):
                key = "saturated_by_design"
            keys.append(key)
        out[m] = keys
    return out


def frames_in(dive_id: int | None, t_from: float | None, t_to: float | None) -> Any:
    q = select(Frame.id)
    if dive_id is not None:
        q = q.where(Frame.dive_id == dive_id)
    if t_from is not None:
        q = q.where(Frame.captured_unix_s >= t_from)
    if t_to is not None:
        q = q.where(Frame.captured_unix_s <= t_to)
    return q


def frame_modules(s: Session, frame_ids: Iterable[int]) -> dict[int, str]:
    """The module of each of the given frames."""
    ids = list(frame_ids)
    out: dict[int, str] = {}
    for i in range(0, len(ids), 500):
        q = select(Frame.id, Frame.module_id).where(Frame.id.in_(ids[i : i + 500]))
        out.update((int(f), m) for f, m in s.execute(q))
    return out


def locate_frames(
    s: Session, keys: Iterable[tuple[str, str, int]]
) -> dict[tuple[str, str, int], tuple[int, int]]:
    """(frame id, dive id) of stored frames by (module, boot, seq); keys not stored are left out."""
    keys = list(dict.fromkeys(keys))
    out: dict[tuple[str, str, int], tuple[int, int]] = {}
    for i in range(0, len(keys), 500):
        q = select(Frame.id, Frame.dive_id, Frame.module_id, Frame.boot, Frame.seq).where(
            tuple_(Frame.module_id, Frame.boot, Frame.seq).in_(keys[i : i + 500])
        )
        for fid, did, m, b, seq in s.execute(q):
            out[(m, b, int(seq))] = (int(fid), int(did))
    return out


def dive_frames(
    s: Session, dive_id: int, t_from: float | None = None, t_to: float | None = None
) -> list[tuple[int, str]]:
    """(frame id, relative path) of every frame of a dive (captured in [t_from, t_to] if given)."""
    q = select(Frame.id, Frame.path).where(Frame.id.in_(frames_in(dive_id, t_from, t_to)))
    return [(int(i), p) for i, p in s.execute(q.order_by(Frame.id))]


def dives_with_frames(s: Session, t_from: float | None = None, t_to: float | None = None) -> list[Dive]:
    """The dives holding frames captured in [t_from, t_to], oldest first."""
    ids = select(Frame.dive_id).where(Frame.id.in_(frames_in(None, t_from, t_to))).distinct()
    return list(s.scalars(select(Dive).where(Dive.id.in_(ids)).order_by(Dive.id)))
