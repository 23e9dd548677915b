"""Every route that serves a file refuses to leave its folder, against the real server process.

Requests go out through ``http.client`` so the path reaches the server exactly
as written (an HTTP library would normalise ``..`` away before sending it).
"""

from __future__ import annotations

import contextlib
import http.client
import os
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest

from tests.utils.system import System, wait_until

pytestmark = pytest.mark.browser

SECRET = b"root:"  # the first line of /etc/passwd


def raw_get(system: System, path: str) -> tuple[int, bytes]:
    u = urlsplit(system.base_url)
    conn = http.client.HTTPConnection(u.hostname, u.port, timeout=10)
    try:
        conn.putrequest("GET", path, skip_accept_encoding=True)
        conn.endheaders()
        res = conn.getresponse()
        return res.status, res.read()
    finally:
        conn.close()


@pytest.mark.parametrize(
    "path",
    [
        "/static/../../../../etc/passwd",
        "/static/%2e%2e/%2e%2e/%2e%2e/%2e%2e/etc/passwd",
        "/static/%2e%2e%2f%2e%2e%2f%2e%2e%2f%2e%2e%2fetc%2fpasswd",
        "/static/..%2f..%2f..%2f..%2fetc%2fpasswd",
        "/static/%252e%252e/%252e%252e/etc/passwd",
        "/static//etc/passwd",
        "/static/..\\..\\..\\..\\etc\\passwd",
        "/static/css/../../../../../../etc/passwd",
        "/static/%00/etc/passwd",
        "/vendor/../../../../etc/passwd",
        "/vendor/plotly.min.js/../../../../etc/passwd",
        "/api/frames/..%2f..%2f..%2fetc%2fpasswd/image",
        "/api/frames/1/..%2f..%2f..%2f..%2fetc%2fpasswd",
        "/../../../../etc/passwd",
        "/review/../../../../etc/passwd",
    ],
)
def test_traversal_in_the_url_is_refused(system: System, path: str) -> None:
    status, body = raw_get(system, path)
    assert status in (400, 404, 405, 422), (path, status)
    assert SECRET not in body


def test_static_files_and_pages_are_served(system: System) -> None:
    for path in ("/", "/review", "/static/css/camcal.css", "/static/js/live.js"):
        status, body = raw_get(system, path)
        assert status == 200 and body, path


@contextlib.contextmanager
def tampered(data: Path, frame_id: int, path: str) -> Iterator[None]:
    """Point a frame's stored path somewhere else for the duration (as a corrupted database would)."""
    db = sqlite3.connect(data / "camcal.db", timeout=30)
    try:
        (old,) = db.execute("SELECT path FROM frames WHERE id = ?", (frame_id,)).fetchone()
        with db:
            db.execute("UPDATE frames SET path = ? WHERE id = ?", (path, frame_id))
        yield
    finally:
        with db:
            db.execute("UPDATE frames SET path = ? WHERE id = ?", (old, frame_id))
        db.close()


def test_a_tampered_frame_path_is_refused(system: System) -> None:
    def first_frame() -> int | None:
        items = httpx.get(system.url("/api/frames?limit=1&order=newest"), timeout=5).json()["items"]
        return items[0]["id"] if items else None

    frame_id = wait_until(first_frame, 90, "a stored frame")
    # A symlink inside the data folder that points out of it: resolved, so refused as well.
    link = system.data / "frames" / "escape.png"
    link.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        link.unlink()
    os.symlink("/etc/passwd", link)
    try:
        for bad in (
            "../../../../../../etc/passwd",
            "/etc/passwd",
            "frames/../../../../../../etc/passwd",
            "frames/escape.png",
        ):
            with tampered(system.data, frame_id, bad):
                for route in ("image", "thumbnail"):
                    status, body = raw_get(system, f"/api/frames/{frame_id}/{route}")
                    if route == "thumbnail" and status == 200:
                        # A thumbnail made before the tampering comes from the thumbs folder: still no secret.
                        assert body.startswith(b"\xff\xd8"), bad
                    else:
                        assert status == 404, (bad, route, status, body[:200])
                        assert b'"error"' in body and SECRET not in body
    finally:
        link.unlink()
    status, _ = raw_get(system, f"/api/frames/{frame_id}/image")
    assert status == 200, "the untampered frame is served again"
