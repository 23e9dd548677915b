"""GET /api/health: are the modules alive, is the ingest running, how deep are the queues.

GET /healthz: does this server answer (a liveness probe for ``camcal up``, Docker, systemd)."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter

from camcal.core import __version__
from server.deps import HubDep, SettingsDep, StoreDep
from server.schemas import Health, Healthz
from storage import queries
from storage.db import database_unavailable

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Healthz)
async def healthz() -> dict[str, str]:
    """200 while the server runs and its store is open; touches neither the ingest nor the database."""
    return {"status": "ok", "version": __version__}


@router.get("/api/health", response_model=Health)
def health(hub: HubDep, store: StoreDep, settings: SettingsDep) -> dict[str, Any]:
    """Per-module link state, last packet age, frames/s and queue depths, from the ingest's heartbeat.

    Without a recent heartbeat from the ingest the modules' state is unknown
    (``link: "unknown"``) and ``ingest.up`` is false. A database that cannot be used makes the
    status ``degraded`` with ``database.error`` saying what to do (the modules then as the ingest
    reports them).
    """
    database: dict[str, Any] = {"ok": True, "error": None}
    try:
        known = store.call(queries.modules)
    except Exception as exc:  # the database is down: say so, with what the ingest still reports
        message = database_unavailable(exc)
        if message is None:
            raise
        known, database = [], {"ok": False, "error": message}
    ingest = hub.ingest_state(settings.stale_after_s)
    health = hub.live_health(settings.stale_after_s)
    live = (health or {}).get("modules", {})
    now = time.time()
    out = {}
    for m in known:
        h = live.get(m["id"])
        out[m["id"]] = {
            "link": h["link"] if h else "unknown",
            "last_packet_age_s": h["last_packet_age_s"] if h else round(now - m["last_seen_unix_s"], 1),
            "frames_per_s": h["frames_per_s"] if h else None,
            "frames_last_min": h.get("frames_last_min") if h else None,
            "last_frame_age_s": h.get("last_frame_age_s") if h else None,
            "schedule": h["schedule"] if h else m["schedule"],
            "outbox_pending": h.get("outbox_pending") if h else None,
            "card_skipped": h.get("card_skipped") if h else None,
            "capture_errors": h.get("capture_errors") if h else None,
            "sensor_errors": h.get("sensor_errors") if h else None,
            "deferred_shots": h.get("deferred_shots") if h else None,
            "clock_offset_s": h.get("clock_offset_s") if h else None,
            "boot": h["boot"] if h else m["boot"],
            "distance_m": m["distance_m"],
            "phase": hub.phase(m["id"]),
        }
    for mid, h in live.items():
        out.setdefault(mid, {**h, "distance_m": None, "phase": hub.phase(mid)})
    return {
        "status": "ok" if ingest["up"] and database["ok"] else "degraded",
        "server": {
            "version": __version__,
            "time_unix_s": now,
            "clients": len(hub.clients),
            "simulation_speed": settings.simulation_speed,
        },
        "database": database,
        "ingest": ingest,
        "modules": out,
        "queues": (health or {}).get("queues"),
        "analysis_ready": (health or {}).get("analysis_ready"),
        "counters": (health or {}).get("counters"),
        "malformed": (health or {}).get("malformed"),
        "nacked": (health or {}).get("nacked"),
        "link_security": (health or {}).get("link_security"),
        "refused_connections": (health or {}).get("refused_connections"),
        "latency_p95_s": (health or {}).get("latency_p95_s"),
    }
