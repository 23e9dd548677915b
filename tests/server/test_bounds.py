"""The server's bounds and hardening, in process: headers, bodies, tokens, queues, files.

The real-process checks (a 50 MB body, a WebSocket asking for snapshots,
symbolic links over real HTTP, TLS) are in ``tests/live/test_http_bounds.py``.
"""

from __future__ import annotations

import io
import os
import re
import tempfile
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.guard import CSP
from server.settings import ServerSettings
from storage.store import Store
from tests.server.conftest import TOKEN
from tests.server.test_extreme_rows import get_paths
from tests.utils.dive_store import copy_data

AUTH = {"Authorization": f"Bearer {TOKEN}"}
HEADERS = {
    "content-security-policy": CSP,
    "x-content-type-options": "nosniff",
    "x-frame-options": "DENY",
    "referrer-policy": "no-referrer",
}


@pytest.fixture
def data(dive_data, tmp_path: Path) -> Path:
    return copy_data(dive_data[0], tmp_path / "data")


@pytest.fixture
def app_client(data: Path) -> Iterator[TestClient]:
    settings = ServerSettings(
        data_dir=data, events=None, operator_tokens={"deck": TOKEN}, token_failures=5, token_window_s=60
    )
    with TestClient(create_app(settings), raise_server_exceptions=False) as c:
        yield c


def assert_secure(response, what: str) -> None:
    for name, value in HEADERS.items():
        assert response.headers.get(name) == value, f"{what}: {name} is {response.headers.get(name)!r}"


def test_every_page_and_api_response_carries_the_security_headers(client: TestClient) -> None:
    paths = [p for p in get_paths(client.app.routes) if "{" not in p] + [
        "/api/frames/1/image",
        "/api/dives/999999",
        "/static/css/camcal.css",
        "/static/js/live.js",
        "/vendor/plotly.min.js",
        "/no/such/page",
    ]
    assert len(paths) > 25
    for path in paths:
        assert_secure(client.get(path), f"GET {path}")
    assert_secure(client.post("/api/dives/1/reanalyses", json={}), "POST without a token (401)")
    assert_secure(client.post("/api/schedules/preview", content=b"x" * (2 << 20)), "413")
    csp = dict(p.strip().split(" ", 1) for p in CSP.split(";"))
    assert csp["script-src"] == "'self'" and csp["frame-ancestors"] == "'none'"
    assert csp["default-src"] == "'self'" and csp["object-src"] == "'none'"


def test_pages_have_no_inline_script_and_the_docs_no_cdn(client: TestClient) -> None:
    for page in ("/", "/review", "/control", "/docs", "/redoc"):
        html = client.get(page).text
        assert not re.search(r"<script(?![^>]*\bsrc=)[^>]*>", html), f"{page} has an inline script"
        assert "cdn" not in html.lower() and "https://" not in html, page
    for asset in ("swagger-ui-bundle.js", "swagger-ui.css", "redoc.standalone.js"):
        r = client.get(f"/vendor/docs/{asset}")
        assert r.status_code == 200 and len(r.content) > 10_000, asset
    assert client.get("/vendor/docs/../../camcal.db").status_code == 404


def test_a_body_over_the_limit_is_refused_before_it_is_read(client: TestClient) -> None:
    r = client.post("/api/schedules/preview", content=b"{" * (1 << 20 | 1))
    assert r.status_code == 413 and r.json()["error"]["code"] == "too_large"

    def chunks() -> Iterator[bytes]:  # no Content-Length: counted as it arrives
        for _ in range(40):
            yield b" " * 65536

    r = client.post("/api/schedules/preview", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413, r.text


def test_the_openapi_document_has_bearer_auth_and_every_error(client: TestClient) -> None:
    doc = client.get("/openapi.json").json()
    assert doc["components"]["securitySchemes"]["HTTPBearer"] == {
        "type": "http",
        "scheme": "bearer",
        "description": "An operator token (CAMCAL_OPERATOR_TOKENS)",
    }
    ack = doc["paths"]["/api/alarms/{alarm_id}/ack"]["post"]
    assert ack["security"] == [{"HTTPBearer": []}]
    assert {"401", "403", "404", "413", "422", "429"} <= set(ack["responses"])
    assert "409" in doc["paths"]["/api/modules/{module_id}/schedule"]["post"]["responses"]
    image = doc["paths"]["/api/frames/{frame_id}/image"]["get"]["responses"]
    assert {"404", "410", "422"} <= set(image)
    assert "security" not in doc["paths"]["/api/dives"]["get"]


def test_wrong_tokens_are_rate_limited_per_address(app_client: TestClient) -> None:
    url = "/api/alarms/999999/ack"
    for _ in range(5):
        assert app_client.post(url, headers={"Authorization": "Bearer wrong-token-1"}).status_code == 403
    r = app_client.post(url, headers=AUTH)  # even the right token waits now
    assert r.status_code == 429 and int(r.headers["retry-after"]) >= 1
    assert r.json()["error"]["code"] == "too_many_failures"
    assert app_client.get("/api/dives").status_code == 200, "reading needs no token and is not held off"


def test_the_ack_note_is_kept_in_the_audit_log(app_client: TestClient, data: Path) -> None:
    store = Store.open(data, run_migrations=False)
    try:
        alarm, _ = store.raise_alarm("test:note", "test", "MINOR", "a test alarm", "A")
    finally:
        store.close()
    r = app_client.post(f"/api/alarms/{alarm.id}/ack", json={"note": "checked the housing"}, headers=AUTH)
    assert r.status_code == 200, r.text
    entry = next(a for a in app_client.get("/api/audit").json() if a["action"] == "alarm.ack")
    assert entry["details"]["note"] == "checked the housing" and entry["actor"] == "deck"


def test_reanalyses_wait_in_a_queue_and_run_one_at_a_time(data: Path) -> None:
    settings = ServerSettings(
        data_dir=data, events=None, operator_tokens={"deck": TOKEN}, max_reanalyses_queued=2
    )
    with TestClient(create_app(settings)) as c:
        dive = c.get("/api/dives").json()[0]["id"]
        url = f"/api/dives/{dive}/reanalyses"
        answers = [c.post(url, json={"linear_range": [6.0, 230.0 + i]}, headers=AUTH) for i in range(6)]
        codes = [a.status_code for a in answers]
        assert codes[:3] == [202, 202, 202] and 503 in codes[3:], codes
        busy = next(a for a in answers if a.status_code == 503)
        assert busy.headers["retry-after"] and busy.json()["error"]["code"] == "unavailable"
        most_running = 0
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline:
            runs = [r for r in c.get(f"/api/dives/{dive}/runs").json() if r["kind"] == "reanalysis"]
            most_running = max(most_running, sum(r["status"] == "running" for r in runs))
            if all(r["status"] in ("done", "failed", "cancelled") for r in runs):
                break
            time.sleep(0.05)
        statuses = sorted(r["status"] for r in runs)
        assert statuses.count("done") >= 3 and most_running == 1, (statuses, most_running)


def test_exports_beyond_the_bound_are_refused_and_one_is_streamed(app_client: TestClient) -> None:
    dive = app_client.get("/api/dives").json()[0]["id"]
    slots = app_client.app.state.exports
    slots.take()  # an export in progress
    try:
        r = app_client.get(f"/api/dives/{dive}/export")
        assert r.status_code == 503 and r.headers["retry-after"]
    finally:
        slots.give()
    before = {p for p in os.listdir(tempfile.gettempdir()) if p.startswith("camcal-export-")}
    r = app_client.get(f"/api/dives/{dive}/export")
    assert r.status_code == 200 and r.content[:2] == b"PK"
    with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
        assert "frames.csv" in zf.namelist()
    after = {p for p in os.listdir(tempfile.gettempdir()) if p.startswith("camcal-export-")}
    assert after <= before, "the export's temporary file is left behind"


def test_ids_made_of_dots_are_refused(app_client: TestClient, data: Path) -> None:
    # Percent-encoded, so that the client sends the dots as they are (it would resolve a bare "..").
    for path in ("/api/modules/%2e%2e/commands", "/api/modules/%2e", "/api/modules/.../commands"):
        r = app_client.get(path)
        assert r.status_code == 422 and "module_id" in r.json()["error"]["message"], (path, r.text)
    r = app_client.post("/api/modules/%2e%2e/schedule", json={}, headers=AUTH)
    assert r.status_code == 422
    store = Store.open(data, run_migrations=False)
    try:
        from storage.files import UnsafePath

        for module, boot in (("..", "b"), ("A", ".."), (".", "b")):
            with pytest.raises(UnsafePath):
                store.files.relative_path(1, module, boot, 1)
    finally:
        store.close()
