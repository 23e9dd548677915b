"""The server's bounds against a real ``camcal serve`` process, over real sockets.

A 50 MB body without a token is answered before the server reads it, and
its memory does not grow; a browser that asks for a snapshot a hundred
times gets two; files replaced by symbolic links (to the database) or by
bytes that are not an image are never served; HTTPS works with the
configured certificate. The figures (time to the answer, memory, CPU) are
printed for the report; what is asserted is the behaviour.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
import sqlite3
import ssl
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect

from server.guard import CSP
from tests.utils.dive_store import copy_data
from tests.utils.system import camcal_serve

MB = 1024 * 1024
TOKEN = "a-long-operator-token-for-tests"


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise AssertionError("no VmRSS")


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.fixture(scope="module")
def served(dive_data, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, int, Path]]:
    data = copy_data(dive_data[0], tmp_path_factory.mktemp("http") / "data")
    env = {"CAMCAL_OPERATOR_TOKENS": json.dumps({"deck": TOKEN})}
    with camcal_serve(data, env=env) as (url, proc):
        yield url, proc.pid, data


def post_headers(url: str, path: str, length: int | None) -> tuple[socket.socket, bytes]:
    host, port = url.removeprefix("http://").split(":")
    sock = socket.create_connection((host, int(port)), timeout=10)
    size = f"Content-Length: {length}\r\n" if length is not None else "Transfer-Encoding: chunked\r\n"
    head = f"POST {path} HTTP/1.1\r\nHost: {host}\r\nContent-Type: application/json\r\n{size}\r\n"
    return sock, head.encode()


def test_a_50_mb_post_without_a_token_is_refused_before_its_body_is_read(served) -> None:
    url, pid, _ = served
    dive = httpx.get(f"{url}/api/dives").json()[0]["id"]
    before = rss_kib(pid)
    sock, head = post_headers(url, f"/api/dives/{dive}/reanalyses", 50 * MB)
    t0 = time.perf_counter()
    sock.sendall(head)  # the headers only: the answer must not wait for the body
    answer = sock.recv(65536)
    elapsed_ms = (time.perf_counter() - t0) * 1000
    while b"too_large" not in answer:  # the body may come in a packet of its own
        more = sock.recv(65536)
        if not more:
            break
        answer += more
    assert answer.startswith(b"HTTP/1.1 413"), answer[:200]
    assert b"too_large" in answer and b"content-security-policy" in answer.lower()
    sent = 0
    chunk = b"x" * MB
    try:  # a client that sends it all the same: the server has closed the connection
        while sent < 50 * MB:
            sock.sendall(chunk)
            sent += len(chunk)
    except OSError:
        pass
    sock.close()
    # And a chunked body (no Content-Length): cut off at the limit.
    sock, head = post_headers(url, f"/api/dives/{dive}/reanalyses", None)
    sock.sendall(head)
    chunked = 0
    try:
        for _ in range(50):
            sock.sendall(b"%x\r\n" % MB + chunk + b"\r\n")
            chunked += MB
    except OSError:
        pass
    reply = b""
    with contextlib.suppress(OSError):
        reply = sock.recv(4096)
    sock.close()
    grown_kib = rss_kib(pid) - before
    print(
        f"50 MB POST: 413 after {elapsed_ms:.1f} ms with no body byte sent; the client then got "
        f"{sent / MB:.0f} MB through; chunked without a token: {chunked / MB:.0f} MB sent, {reply[:12]!r}; "
        f"server memory {before / 1024:.0f} -> {rss_kib(pid) / 1024:.0f} MiB"
    )
    assert reply.startswith(b"HTTP/1.1 4") or reply == b"", reply[:100]  # refused, or cut off
    assert grown_kib < 8 * 1024, f"the server's memory grew by {grown_kib / 1024:.1f} MiB"
    assert httpx.get(f"{url}/api/health", timeout=5).status_code == 200


def test_100_resyncs_on_one_socket_cost_two_snapshots(served) -> None:
    url, pid, _ = served
    with connect(url.replace("http", "ws") + "/ws/live", max_size=2**24) as ws:
        assert json.loads(ws.recv(timeout=10))["type"] == "snapshot"
        t_cpu = cpu_s(pid)
        for _ in range(100):
            ws.send(json.dumps({"type": "resync"}))
        snapshots = 0
        end = time.monotonic() + 3.0
        while time.monotonic() < end:
            try:
                msg = json.loads(ws.recv(timeout=max(0.05, end - time.monotonic())))
            except TimeoutError:
                break
            snapshots += msg.get("type") == "snapshot"
        used = cpu_s(pid) - t_cpu
        print(f"100 resyncs on one socket: {snapshots} snapshots, {used:.2f} s of server CPU")
        assert 1 <= snapshots <= 2, snapshots
        assert used < 1.0, f"{used:.2f} s of CPU"
        ws.send("x" * 10_000)  # over max_ws_message_bytes: the server closes the connection
        with pytest.raises(Exception, match=r"1009|message too big"):
            for _ in range(100):
                ws.recv(timeout=5)


def test_too_many_live_connections_of_one_address_are_closed(served) -> None:
    url, _, _ = served
    ws_url = url.replace("http", "ws") + "/ws/live"
    with contextlib.ExitStack() as stack:
        for _ in range(16):
            stack.enter_context(connect(ws_url, max_size=2**24)).recv(timeout=10)
        # Closed before or after the handshake, whichever the server's WebSocket layer does.
        with pytest.raises(Exception, match=r"1008|403|too many"), connect(ws_url, max_size=2**24) as extra:
            extra.recv(timeout=5)
    with connect(ws_url, max_size=2**24) as again:  # the others closed: room again
        assert json.loads(again.recv(timeout=10))["type"] == "snapshot"


def test_symlinked_and_fake_frame_files_are_never_served(served) -> None:
    url, _, data = served
    db = sqlite3.connect(data / "camcal.db")
    frames = db.execute("SELECT id, path FROM frames ORDER BY id LIMIT 4").fetchall()
    db.close()
    (a, path_a), (b, path_b), (c, _), (d, path_d) = frames
    secret = b"SQLite format 3"
    # A frame file replaced by a link to the database.
    (data / path_a).unlink()
    (data / path_a).symlink_to(data / "camcal.db")
    r = httpx.get(f"{url}/api/frames/{a}/image")
    assert r.status_code == 404 and secret not in r.content, r.text[:200]
    assert "symbolic link" in r.json()["error"]["message"]
    # A thumbnail replaced by a link to the database: made again from the frame, never the link's target.
    thumbs = data / "thumbs"
    thumbs.mkdir(exist_ok=True)
    thumb = thumbs / f"{c}.jpg"
    thumb.unlink(missing_ok=True)
    thumb.symlink_to(data / "camcal.db")
    r = httpx.get(f"{url}/api/frames/{c}/thumbnail")
    assert r.status_code == 200 and r.content[:3] == b"\xff\xd8\xff" and secret not in r.content
    assert not thumb.is_symlink(), "the link is replaced by the thumbnail"
    # A thumbnail of a frame that does not exist is not served, whatever is on disk.
    (thumbs / "987654321.jpg").write_bytes(b"\xff\xd8\xff not a frame of this ship \xff\xd9")
    assert httpx.get(f"{url}/api/frames/987654321/thumbnail").status_code == 404
    # A frame file that is not the PNG its row says is not served as an image.
    (data / path_d).write_bytes(b"<script>alert(1)</script>" + b"\x00" * 64)
    r = httpx.get(f"{url}/api/frames/{d}/image")
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/json"), r.text
    assert r.headers["x-content-type-options"] == "nosniff" and r.headers["content-security-policy"] == CSP
    # Last (it hides its neighbours): a boot folder replaced by a link to a folder holding a database copy.
    boot = (data / path_b).parent
    elsewhere = data.parent / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / Path(path_b).name).write_bytes((data / "camcal.db").read_bytes()[:4096])
    boot.rename(data.parent / "moved-boot")
    boot.symlink_to(elsewhere, target_is_directory=True)
    r = httpx.get(f"{url}/api/frames/{b}/image")
    assert r.status_code == 404 and secret not in r.content


def test_https_with_the_configured_certificate(dive_data, tmp_path: Path) -> None:
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1"),
            *("-keyout", str(key), "-out", str(cert)),
        ],
        check=True,
        capture_output=True,
    )
    data = copy_data(dive_data[0], tmp_path / "data")
    trust = ssl.create_default_context(cafile=str(cert))
    with camcal_serve(data, "--tls-cert", str(cert), "--tls-key", str(key), scheme="https", verify=trust) as (
        url,
        _,
    ):
        r = httpx.get(f"{url}/api/dives", verify=trust)
        assert r.status_code == 200 and r.json()
        assert r.headers["content-security-policy"] == CSP
        with pytest.raises(httpx.HTTPError):
            httpx.get(url.replace("https", "http") + "/api/dives", timeout=5)
