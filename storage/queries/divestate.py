"""Whether a dive is open or has ended, and why: read from what its modules did.

A dive is everything from putting the modules in the water to recovering
them. It has ended when

* an operator ended it (``camcal dive end``): the reason is stored;
* every module that recorded into it is back on deck (it had been deeper
  than ``deck_depth_m`` and its newest depth reading is shallower) and has
  signed off (said ``bye``);
* every module is back on deck and no frame of any of them has been
  received for ``quiet_s`` (a module left running, or switched off without
  signing off, on deck).

Otherwise it is open, whatever the time: a restart of the ship's software or
of a module in the middle of a dive continues it. An ended dive that was not
ended by hand is recorded as ended (with its reason) by the next start of
``camcal up`` or ``camcal ingest``, which then begins a new dive
(`storage.store.Store.dive_to_record`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from storage.models import Dive, Frame, SensorSample
from storage.models import Event as EventRow

#: The sensors' depth column (the sensor columns are made from the wire's definition).
_SAMPLE_DEPTH = SensorSample.__table__.c.depth_m


@dataclass(frozen=True)
class DiveRules:
    """When a dive is over (`camcal.core.settings.Settings`: ``deck_depth_m``, ``dive_quiet_s``)."""

    #: A module shallower than this is on deck (or at the surface beside the ship).
    deck_depth_m: float = 10.0
    #: Every module back on deck and no frame received for this long: the dive has ended.
    quiet_s: float = 1800.0


@dataclass(frozen=True)
class DiveState:
    """``open`` or ``ended``, why, and since when (ship's clock; None while open)."""

    state: str
    reason: str
    ended_unix_s: float | None = None
    #: True when the end follows from what the modules did but is not recorded yet (the next start
    #: records it); False when it is recorded (by an operator or a start) or the dive is open.
    derived: bool = False

    def as_dict(self) -> dict[str, Any]:
        return {
            "state": self.state,
            "state_reason": self.reason,
            "state_ended_unix_s": self.ended_unix_s,
        }


@dataclass(frozen=True)
class _Module:
    id: str
    deepest_m: float | None
    depth_now_m: float | None
    signed_off_unix_s: float | None
    #: When the ship received its last frame of the dive (its own clock).
    last_frame_received_unix_s: float | None

    def back_on_deck(self, rules: DiveRules) -> bool:
        return (
            self.deepest_m is not None
            and self.deepest_m > rules.deck_depth_m
            and self.depth_now_m is not None
            and self.depth_now_m < rules.deck_depth_m
        )


def _utc_minute(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.gmtime(t))


def _modules(s: Session, dive_id: int) -> list[_Module]:
    """Each module of the dive: deepest and newest depth (newest: received last), its sign-off."""
    ids = set(s.scalars(select(Frame.module_id).where(Frame.dive_id == dive_id).distinct()))
    ids |= {
        m
        for m in s.scalars(
            select(EventRow.module_id).where(EventRow.kind == "link", EventRow.dive_id == dive_id).distinct()
        )
        if m
    }
    out = []
    for m in sorted(ids):
        f_deep, f_last = s.execute(
            select(func.max(Frame.depth_m), func.max(Frame.received_unix_s)).where(
                Frame.dive_id == dive_id, Frame.module_id == m
            )
        ).one()
        s_deep = s.scalar(
            select(func.max(_SAMPLE_DEPTH)).where(
                SensorSample.module_id == m, SensorSample.dive_id == dive_id
            )
        )
        # The newest reading as received: the sample stored last (its own time is the module's clock).
        now_m = s.scalar(
            select(_SAMPLE_DEPTH)
            .where(
                SensorSample.module_id == m,
                SensorSample.dive_id == dive_id,
                _SAMPLE_DEPTH.is_not(None),
            )
            .order_by(SensorSample.id.desc())
            .limit(1)
        )
        if now_m is None:
            now_m = s.scalar(
                select(Frame.depth_m)
                .where(Frame.dive_id == dive_id, Frame.module_id == m, Frame.depth_m.is_not(None))
                .order_by(Frame.id.desc())
                .limit(1)
            )
        link = s.execute(
            select(EventRow.t_unix_s, EventRow.payload)
            .where(EventRow.kind == "link", EventRow.module_id == m, EventRow.dive_id == dive_id)
            .order_by(EventRow.id.desc())
            .limit(1)
        ).first()
        signed_off = None
        if link is not None and (link[1] or {}).get("state") == "down" and link[1].get("reason") == "bye":
            signed_off = float(link[0])
        deep = [d for d in (f_deep, s_deep) if d is not None]
        out.append(_Module(m, max(deep) if deep else None, now_m, signed_off, f_last))
    return out


def dive_state(
    s: Session, dive: Dive, rules: DiveRules | None = None, now_unix_s: float | None = None
) -> DiveState:
    """Whether ``dive`` is open or has ended, and why (see the module's docstring)."""
    if dive.ended_unix_s:
        return DiveState(
            "ended", dive.end_reason or "ended by an operator (camcal dive end)", dive.ended_unix_s
        )
    rules = rules or DiveRules()
    now = time.time() if now_unix_s is None else now_unix_s
    mods = _modules(s, dive.id)
    if not mods:
        return DiveState("open", "no module has recorded into it yet")
    names = ", ".join(m.id for m in mods)
    if not all(m.back_on_deck(rules) for m in mods):
        deep = [m for m in mods if not m.back_on_deck(rules)]
        where = "; ".join(
            f"{m.id} at {m.depth_now_m:.0f} m" if m.depth_now_m is not None else f"{m.id}: depth unknown"
            for m in deep
        )
        return DiveState("open", f"in the water ({where})")
    signed = [m.signed_off_unix_s for m in mods]
    if all(t is not None for t in signed):
        t_end = max(t for t in signed if t is not None)
        return DiveState(
            "ended",
            f"back on deck and signed off ({names}; the last at {_utc_minute(t_end)} UTC)",
            t_end,
            derived=True,
        )
    last = max((m.last_frame_received_unix_s or 0.0) for m in mods) or None
    if last is not None and now - last >= rules.quiet_s:
        return DiveState(
            "ended",
            f"back on deck ({names}) and no frame for {rules.quiet_s / 60:.0f} min "
            f"(the last received at {_utc_minute(last)} UTC)",
            last,
            derived=True,
        )
    left = (
        ""
        if last is None
        else f"; it ends {max(0.0, rules.quiet_s - (now - last)) / 60:.0f} min from now without a frame"
    )
    return DiveState("open", f"back on deck ({names}), not signed off{left}")
