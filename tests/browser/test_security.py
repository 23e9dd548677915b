"""The real system (``camcal up``) seen by a cautious operator: offline docs, headers, secrets, intruders.

`/docs` and `/redoc` render in Chromium with every request outside the
camcal server blocked (no CDN) and no Content-Security-Policy violation;
every page carries the security headers; the operator token given in the
environment is never printed and no child process of ``camcal up`` has it;
and connections with unknown keys show on the live page as refused
connections, not as modules.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
import pytest
import zmq

from server.guard import CSP
from tests.browser.conftest import camcal_page
from tests.utils.system import System

pytestmark = pytest.mark.browser


def csp_errors(pg: Any) -> list[str]:
    found: list[str] = []
    pg.on("console", lambda m: found.append(m.text) if "Content Security Policy" in m.text else None)
    return found


@pytest.mark.parametrize(("path", "ready"), [("/docs", ".opblock"), ("/redoc", "[data-section-id]")])
def test_the_api_docs_render_with_the_network_blocked(
    browser: Any, system: System, artifacts: Path, path: str, ready: str
) -> None:
    with camcal_page(browser, system) as pg:  # any request outside the camcal server fails the test
        violations = csp_errors(pg)
        pg.goto(system.url(path))
        pg.wait_for_selector(ready, timeout=30_000)
        assert pg.locator(ready).count() >= 10, f"{path} shows too few operations"
        pg.screenshot(path=str(artifacts / f"docs{path.replace('/', '-')}.png"))
        # Nothing is blocked by the policy (ReDoc's footer logo from cdn.redoc.ly is asked for no
        # more: `server.routers.pages.OFFLINE`); a block would mean a part of the page is missing.
        assert violations == [], violations


def test_every_page_carries_the_security_headers(system: System) -> None:
    for path in ("/", "/review", "/control", "/docs", "/redoc", "/api/health", "/static/js/live.js", "/nope"):
        r = httpx.get(system.url(path), timeout=10)
        assert r.headers["content-security-policy"] == CSP, path
        assert r.headers["x-content-type-options"] == "nosniff", path
        assert r.headers["x-frame-options"] == "DENY" and r.headers["referrer-policy"] == "no-referrer", path


def test_the_token_is_never_printed_nor_handed_to_the_children(system: System) -> None:
    assert system.token not in system.log.read_text(errors="replace"), "camcal up printed a configured token"
    children = system.children_when_up  # read from /proc when camcal up said it is up
    assert len(children) >= 3, children  # the ingest and two modules
    for pid, (environ, cmdline) in children.items():
        assert system.token.encode() not in environ + cmdline, f"child {pid} holds the token"
        assert b"CAMCAL_OPERATOR_TOKENS" not in environ
        if b"simulate" in cmdline:
            assert b"--keys" in cmdline and b"--dive" in cmdline
    keys = system.data / "keys"
    assert (keys / "ship.key_secret").stat().st_mode & 0o077 == 0
    assert {p.name for p in (keys / "modules").glob("*.key")} == {"A.key", "B.key"}


def test_connections_with_unknown_keys_show_as_refused_not_as_modules(
    browser: Any, system: System, artifacts: Path
) -> None:
    ctx = zmq.Context.instance()
    socks = []
    for i in range(5):
        public, secret = zmq.curve_keypair()
        ship = (system.data / "keys" / "ship.key").read_text()
        s = ctx.socket(zmq.DEALER)
        s.setsockopt(zmq.LINGER, 0)
        s.curve_serverkey = ship.split('public-key = "')[1].split('"')[0].encode()
        s.curve_publickey, s.curve_secretkey = public, secret
        s.setsockopt(zmq.ROUTING_ID, f"intruder{i}".encode())
        s.connect(f"tcp://127.0.0.1:{system.ingest_port}")
        socks.append(s)
    try:
        with camcal_page(browser, system) as pg:
            pg.goto(system.url("/"))
            box = pg.locator("#refused")
            box.wait_for(state="visible", timeout=20_000)
            text = box.inner_text()
            assert "Refused connections: " in text and "unknown key" in text and "127.0.0.1" in text, text
            time.sleep(1.5)
            cards = pg.locator(".card h2, .card .module-id").all_inner_texts()
            assert not [c for c in cards if "intruder" in c], cards
            pg.locator("#alarms-panel").scroll_into_view_if_needed()
            pg.screenshot(path=str(artifacts / "live-refused-connections.png"))
        health = httpx.get(system.url("/api/health"), timeout=10).json()
        assert not [m for m in health["modules"] if m.startswith("intruder")]
        assert health["refused_connections"]["total"] >= 5 and health["link_security"] == "curve"
        alarms = httpx.get(system.url("/api/alarms"), timeout=10).json()
        assert not [a for a in alarms if "intruder" in (a["module"] or "") + a["message"]]
    finally:
        for s in socks:
            s.close()
