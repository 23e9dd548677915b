"""WS /ws/live: one WebSocket per browser; a snapshot first, then sequenced events."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from fastapi.concurrency import run_in_threadpool
from sqlalchemy.orm import Session

from server.deps import HubDep, SettingsDep, StoreDep
from server.relay import LiveHub, encode_for
from server.saturation import newest_results, quality_split, saturated_by_design, setting_key
from server.schemas import LiveSnapshot
from server.settings import ServerSettings
from storage import queries
from storage.db import database_unavailable
from storage.store import Store

router = APIRouter(tags=["live"])
#: How long a batching connection gathers events after the first one, and how many at most.
BATCH_WINDOW_S = 0.05
BATCH_MAX = 200
#: A connection gets at most one snapshot per this many seconds, however often it asks.
RESYNC_EVERY_S = 1.0
#: A snapshot the database could not give is tried again after this many seconds.
DATABASE_RETRY_S = 5.0
#: WebSocket close codes: a message too big, too many connections of one address.
CLOSE_TOO_BIG, CLOSE_POLICY = 1009, 1008


def build_snapshot(store: Store, hub: LiveHub, settings: ServerSettings) -> dict[str, Any]:
    """Everything the live view shows, as of now."""
    r = store.call(_snapshot_reads, settings)  # one session: the snapshot is consistent
    dive, run_id, latest, attenuation = r["dive"], r["run_id"], r["latest"], r["attenuation"]
    by_design = r["by_design"]
    ingest = hub.ingest_state(settings.stale_after_s)
    live = (hub.live_health(settings.stale_after_s) or {}).get("modules", {})
    out_modules = {}
    for m in r["modules"]:
        mid = m["id"]
        h = live.get(mid)
        frame = latest.get(mid)
        if frame:
            frame = {**frame, "thumbnail_url": f"/api/frames/{frame['id']}/thumbnail"}
            if frame.get("reason") == "saturated":
                key = setting_key(frame["wavelength_nm"], frame["exposure_s"], frame["gain_db"])
                frame["by_design"] = key in by_design.get(mid, frozenset())
        out_modules[mid] = {
            "id": mid,
            "distance_m": m["distance_m"],
            "link": h["link"] if h else "unknown",
            "last_packet_age_s": h["last_packet_age_s"] if h else None,
            "last_seen_unix_s": m["last_seen_unix_s"],
            "frames_per_s": h["frames_per_s"] if h else None,
            "frames_last_min": h.get("frames_last_min") if h else None,
            "deferred_shots": h.get("deferred_shots") if h else None,
            "last_frame_age_s": h.get("last_frame_age_s") if h else None,
            "schedule": h["schedule"] if h else m["schedule"],
            "latest_frame": frame,
            "sensors": hub.sensors.get(mid) or r["sensors"].get(mid),
            "attitude": hub.attitude.get(mid) or r["attitude"].get(mid),
            "phase": hub.phase(mid),
            "quality": quality_split(
                r["quality"].get(mid, {}), r["saturated"].get(mid, {}), by_design.get(mid, frozenset())
            ),
            "saturated_by_design": sorted(by_design.get(mid, frozenset())),
            "quality_recent": r["recent_quality"].get(mid, {}),
            "recent_outcomes": r["recent_outcomes"].get(mid, []),
        }
    return {
        "server_time_unix_s": time.time(),
        "dive": dive,
        "run_id": run_id,
        "ingest": ingest,
        "stale_after_s": settings.stale_after_s,
        "station_depth_m": settings.station_depth_m,
        "simulation_speed": settings.simulation_speed,
        "modules": out_modules,
        "attenuation": {str(k): _newest(v, 300) for k, v in attenuation.items()},
        "alarms": r["alarms"],
        "refused_connections": (hub.live_health(settings.stale_after_s) or {}).get("refused_connections"),
        "last_event_id": hub.last_event_id,
    }


def _newest(points: list[dict[str, Any]], n: int) -> list[dict[str, Any]]:
    """The ``n`` λ_att points stored last (a visit's point is numbered when the visit begins), in
    time order: not the ``n`` of the latest times, which a module's clock decides."""
    keep = {id(p) for p in sorted(points, key=lambda p: p["id"])[-n:]}
    return [p for p in points if id(p) in keep]


def _snapshot_reads(s: Session, settings: ServerSettings) -> dict[str, Any]:
    """The snapshot's reads, in one session."""
    newest = queries.newest_dive_id(s)
    dive = queries.dives(s, newest, settings.dive_rules)[0] if newest is not None else None
    run_id = queries.live_run_id(s, dive["id"]) if dive else None
    modules = queries.modules(s)
    latest = queries.latest_frames(s, dive["id"], run_id) if dive else {}
    sensors = queries.latest_sensors(s, dive["id"] if dive else None)
    attitude = queries.latest_attitude(s, dive["id"] if dive else None)
    quality = queries.quality_counts(s, run_id) if run_id else {}
    t_last = max((f["received_unix_s"] for f in latest.values()), default=None)  # the last 10 min
    recent_quality = queries.quality_counts(s, run_id, since=t_last - 600) if run_id and t_last else {}
    by_design = saturated_by_design(newest_results(s), settings.linear_range)

    def expected(module: str, wl: int, exposure_s: float, gain_db: float) -> bool:
        return setting_key(wl, exposure_s, gain_db) in by_design.get(module, frozenset())

    outcomes = queries.recent_outcomes(s, dive["id"], run_id, by_design=expected) if dive and run_id else {}
    saturated = queries.saturated_by_setting(s, run_id) if run_id else {}
    attenuation = queries.attenuation_series(s, run_id) if run_id else {}
    alarms = queries.alarms(s, active=True) + queries.alarms(s, active=False, limit=20)
    return {
        "dive": dive,
        "run_id": run_id,
        "modules": modules,
        "latest": latest,
        "sensors": sensors,
        "attitude": attitude,
        "quality": quality,
        "recent_quality": recent_quality,
        "recent_outcomes": outcomes,
        "by_design": by_design,
        "saturated": saturated,
        "attenuation": attenuation,
        "alarms": alarms,
    }


@router.get("/api/live/snapshot", response_model=LiveSnapshot)
def snapshot(store: StoreDep, hub: HubDep, settings: SettingsDep) -> dict[str, Any]:
    """What a new WebSocket receives first (also for a browser that must resynchronise)."""
    return build_snapshot(store, hub, settings)


@router.websocket("/ws/live")
async def live(ws: WebSocket) -> None:
    """Snapshot, then events, each with the connection's sequence number ``seq``.

    A browser that falls behind loses thumbnails and sensor samples first
    and then gets ``{"type": "missed", "dropped": {...}, "resync": bool}``;
    with ``resync`` it should ask for a new snapshot by sending
    ``{"type": "resync"}``. The ingest never waits for a browser.

    Bounds: requests for snapshots are coalesced (at most one snapshot in
    the making and one per `RESYNC_EVERY_S` per connection, however many
    are asked for); a message from the browser over ``max_ws_message_bytes``
    closes the connection (1009); an address holds at most
    ``max_websockets_per_client`` connections (more are closed, 1008).

    While the database cannot be used, the snapshot is replaced by ``{"type": "error", "code":
    "database_unavailable", "message": ...}`` (what to do) and tried again every
    `DATABASE_RETRY_S`; events from the ingest keep coming meanwhile.

    A browser that sends ``{"type": "batch"}`` gets the events that arrive
    within ``BATCH_WINDOW_S`` of each other in one WebSocket message,
    ``{"type": "batch", "messages": [...]}`` (each with its own ``seq``): one
    send per burst instead of one per event, which is what twenty browsers
    cost the ship when frames come fast.
    """
    app = ws.app
    hub: LiveHub = app.state.hub
    store: Store = app.state.store
    settings: ServerSettings = app.state.settings
    address = ws.client.host if ws.client else "unknown"
    if hub.connections_of(address) >= settings.max_websockets_per_client:
        await ws.close(CLOSE_POLICY, "too many live connections from this address")
        return
    await ws.accept()
    client = hub.register(address)
    wanted = asyncio.Event()  # a snapshot was asked for (set again while one is made: one more)
    sending = asyncio.Lock()  # one sender at a time on the socket

    async def send_snapshot() -> None:
        try:
            data = await run_in_threadpool(build_snapshot, store, hub, settings)
        except Exception as exc:  # a database that cannot be used: said, and asked again later
            message = database_unavailable(exc)
            if message is None:
                raise
            async with sending:
                await ws.send_text(
                    json.dumps(
                        {
                            "type": "error",
                            "seq": client.next_seq(),
                            "code": "database_unavailable",
                            "message": message,
                        }
                    )
                )
            asyncio.get_running_loop().call_later(DATABASE_RETRY_S, wanted.set)  # then again
            return
        async with sending:
            await ws.send_text(
                json.dumps({"type": "snapshot", "seq": client.next_seq(), "data": data}, default=str)
            )

    try:
        await send_snapshot()

        async def receive() -> None:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    raise WebSocketDisconnect(msg.get("code", 1000))
                text = msg.get("text") or (msg.get("bytes") or b"").decode("utf-8", "replace")
                if len(text) > settings.max_ws_message_bytes:
                    await ws.close(CLOSE_TOO_BIG, "message too big")
                    return
                try:
                    req = json.loads(text)
                except json.JSONDecodeError:
                    continue
                if isinstance(req, dict) and req.get("type") == "batch":
                    client.batch = True
                elif isinstance(req, dict) and req.get("type") == "resync":
                    client.resync = False
                    wanted.set()

        async def snapshots() -> None:
            """Answer requests for snapshots, coalesced: at most one per `RESYNC_EVERY_S`."""
            while True:
                await wanted.wait()
                wanted.clear()
                await send_snapshot()
                await asyncio.sleep(RESYNC_EVERY_S)

        async def send() -> None:
            while True:
                message = await client.queue.get()
                batch = [message]
                if client.batch:
                    await asyncio.sleep(BATCH_WINDOW_S)
                    while len(batch) < BATCH_MAX and not client.queue.empty():
                        batch.append(client.queue.get_nowait())
                async with sending:
                    if client.dropped:
                        dropped, client.dropped = dict(client.dropped), type(client.dropped)()
                        missed = {
                            "type": "missed",
                            "seq": client.next_seq(),
                            "dropped": dropped,
                            "resync": client.resync,
                        }
                        await ws.send_text(json.dumps(missed))
                    if len(batch) == 1:
                        await ws.send_text(encode_for(message, client.next_seq()))
                    else:
                        texts = ",".join(encode_for(m, client.next_seq()) for m in batch)
                        await ws.send_text(f'{{"type":"batch","messages":[{texts}]}}')

        tasks = [asyncio.create_task(t) for t in (receive(), send(), snapshots())]
        done, pending = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        for t in pending:
            t.cancel()
        for t in done:
            with contextlib.suppress(WebSocketDisconnect, asyncio.CancelledError, RuntimeError):
                t.result()
    except WebSocketDisconnect:
        pass
    finally:
        hub.unregister(client)
