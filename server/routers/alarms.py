"""Alarms and their acknowledgement; the audit log."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Query
from fastapi.concurrency import run_in_threadpool

from server.deps import HubDep, IdPath, OperatorDep, StoreDep
from server.errors import NotFound
from server.schemas import AckRequest, AlarmPublic
from storage import queries

router = APIRouter(tags=["alarms"])


@router.get("/api/alarms", response_model=list[AlarmPublic])
async def list_alarms(
    store: StoreDep, active: bool | None = None, limit: Annotated[int, Query(ge=1, le=2000)] = 200
) -> list[dict[str, Any]]:
    """Alarms, newest first: severity MINOR or MAJOR, raised, cleared, acknowledged by whom."""

    def q() -> list[dict[str, Any]]:
        with store.read() as s:
            return queries.alarms(s, active=active, limit=limit)

    return await run_in_threadpool(q)


@router.post("/api/alarms/{alarm_id}/ack", response_model=AlarmPublic)
async def ack(
    alarm_id: IdPath, store: StoreDep, hub: HubDep, who: OperatorDep, body: AckRequest | None = None
) -> dict[str, Any]:
    """Acknowledge an alarm (operator token); recorded in the audit log with the operator's note.

    Every connected browser hears of it as a live ``alarm`` event with
    ``state: "acked"`` (not stored: the alarm row itself records the ack).
    """
    alarm = await run_in_threadpool(store.ack_alarm, alarm_id, who, body.note if body else "")
    if alarm is None:
        raise NotFound(f"no alarm {alarm_id}")
    out = queries.alarm_dict(alarm)
    hub.deliver(
        {
            "kind": "alarm",
            "id": None,
            "module": out["module"],
            "t": time.time(),
            "payload": {"alarm_id": out["id"], "state": "acked", **out},
        }
    )
    return out


@router.get("/api/audit")
async def audit(
    store: StoreDep,
    limit: Annotated[int, Query(ge=1, le=5000)] = 500,
    offset: Annotated[int, Query(ge=0, le=10_000_000)] = 0,
) -> list[dict[str, Any]]:
    """The append-only audit log: commands, acknowledgements, calibration changes."""

    def q() -> list[dict[str, Any]]:
        with store.read() as s:
            return queries.audit(s, limit, offset)

    return await run_in_threadpool(q)
