"""The server when its database cannot be reached: a real ``camcal serve`` on PostgreSQL through a TCP
relay that is cut (as a failed database host or network would be), then restored.

What a person sees must say what is wrong and what to do, not "internal error"; the live
WebSocket stays open and says so instead of looking like a lost connection; all of it recovers
by itself.
"""

from __future__ import annotations

import json
from pathlib import Path

import httpx
from websockets.sync.client import connect

from tests.utils.live import wait_for
from tests.utils.pg import served_on_a_relayed_database


def test_a_database_that_cannot_be_reached_is_said_and_the_server_recovers(
    tmp_path: Path, pg_template: tuple[str, str] | None
) -> None:
    with served_on_a_relayed_database(tmp_path / "data", pg_template) as (base, proxy):
        assert httpx.get(f"{base}/api/health").json()["database"] == {"ok": True, "error": None}
        with connect(f"{base.replace('http', 'ws')}/ws/live", open_timeout=10) as ws:
            assert json.loads(ws.recv(10))["type"] == "snapshot"

            proxy.cut()
            health = httpx.get(f"{base}/api/health", timeout=30)
            assert health.status_code == 200  # health still answers: with what is wrong
            body = health.json()
            assert body["status"] == "degraded" and body["database"]["ok"] is False
            assert "camcal doctor" in body["database"]["error"]
            dives = httpx.get(f"{base}/api/dives", timeout=30)
            assert dives.status_code == 503 and dives.headers["retry-after"] == "5"
            error = dives.json()["error"]
            assert error["code"] == "database_unavailable" and "Nothing is lost" in error["message"]
            documented = httpx.get(f"{base}/openapi.json").json()["paths"]["/api/dives"]["get"]["responses"]
            assert "database_unavailable" in documented["503"]["description"]  # an answer it documents

            ws.send(json.dumps({"type": "resync"}))  # a snapshot asked for while it is down
            said = json.loads(ws.recv(30))
            assert said["type"] == "error" and said["code"] == "database_unavailable"

            proxy.restore()
            assert wait_for(lambda: httpx.get(f"{base}/api/dives", timeout=30).status_code == 200, 30)
            assert json.loads(ws.recv(30))["type"] == "snapshot"  # asked again by the server itself
            assert httpx.get(f"{base}/api/health").json()["database"]["ok"] is True
