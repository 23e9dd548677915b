"""A slow query never stalls the live view: routes reach the store from FastAPI's threadpool.

A real uvicorn server (in a thread, on a real port) relays the heartbeat an
ingest publishes over ZeroMQ to a real WebSocket client. One route's store
call is made to block (the dive's timeline query waits until the test lets
it go). While it hangs, the WebSocket must keep receiving the heartbeat at
its rate and other routes must answer: the blocked call holds one worker
thread, never the event loop.
"""

from __future__ import annotations

import contextlib
import json
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import uvicorn
import zmq
from websockets.sync.client import connect

from camcal.core.events import Event, EventKind
from server.app import create_app
from server.settings import ServerSettings
from storage import queries
from storage.store import Store
from tests.utils.pace import Pace

HEARTBEAT_S = 0.1


@contextlib.contextmanager
def heartbeat(stop: threading.Event) -> Iterator[str]:
    """An ingest's heartbeat: a ``health`` event every `HEARTBEAT_S` on a real PUB socket."""
    ctx = zmq.Context.instance()
    pub = ctx.socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind("tcp://127.0.0.1:*")
    endpoint = pub.getsockopt(zmq.LAST_ENDPOINT).decode()
    lock = threading.Lock()

    def beat() -> None:
        n = 0
        while not stop.wait(HEARTBEAT_S):
            n += 1
            body = Event(EventKind.HEALTH, {"beat": n, "modules": {}, "queues": {}}, time.time()).to_json()
            with lock:
                pub.send_multipart([b"health", body])

    thread = threading.Thread(target=beat, daemon=True)
    thread.start()
    try:
        yield endpoint
    finally:
        stop.set()
        thread.join(5)
        pub.close(0)


@contextlib.contextmanager
def served(app: Any) -> Iterator[str]:
    """``app`` under a real uvicorn server on a free port, in a thread."""
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", ws="websockets-sansio"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    deadline = time.monotonic() + 15
    while not server.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.02)
    try:
        yield f"127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)
        sock.close()


@pytest.fixture
def blocked_timeline(monkeypatch: pytest.MonkeyPatch) -> Iterator[tuple[threading.Event, threading.Event]]:
    """The timeline query, made to wait (in its worker thread) until ``release`` is set."""
    entered, release = threading.Event(), threading.Event()
    real = queries.timeline

    def slow(s: Any, *args: Any, **kwargs: Any) -> Any:
        entered.set()
        assert release.wait(30), "the test never let the query go"
        return real(s, *args, **kwargs)

    monkeypatch.setattr(queries, "timeline", slow)
    yield entered, release
    release.set()


def test_a_websocket_keeps_its_heartbeat_while_a_query_hangs(tmp_path: Path, blocked_timeline) -> None:
    entered, release = blocked_timeline
    store = Store.open(tmp_path / "data")
    dive = store.create_dive("slow-query")
    stop = threading.Event()
    with heartbeat(stop) as endpoint:
        app = create_app(ServerSettings(data_dir=tmp_path / "data", events=endpoint), store=store)
        with served(app) as host, connect(f"ws://{host}/ws/live", open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "snapshot"

            def beats(seconds: float) -> list[float]:
                """Arrival times of heartbeats over ``seconds``."""
                out, end = [], time.monotonic() + seconds
                while (left := end - time.monotonic()) > 0:
                    try:
                        msg = json.loads(ws.recv(timeout=left))
                    except TimeoutError:
                        break
                    if msg.get("kind") == "health":
                        out.append(time.monotonic())
                return out

            assert beats(1.0), "no heartbeat reached the WebSocket before the slow query"

            answer: dict[str, Any] = {}

            def slow_request() -> None:
                with httpx.Client(timeout=60) as c:
                    answer["response"] = c.get(f"http://{host}/api/dives/{dive.id}/timeline")

            requester = threading.Thread(target=slow_request)
            requester.start()
            assert entered.wait(10), "the timeline query never started"

            # 20 heartbeats are sent in 2 s of an idle machine; a busy one sends them slower (its
            # sender is a thread like any other), so the window and the gap allowed stretch alike.
            pace = Pace()
            window_s = min(pace.bound(2.0), 15.0)  # the query is held 30 s at most
            t0 = time.monotonic()
            during = beats(window_s)
            with httpx.Client(timeout=5) as c:  # other routes answer meanwhile
                t_other = time.monotonic()
                assert c.get(f"http://{host}/api/dives").status_code == 200
                other_s = time.monotonic() - t_other
            assert not answer, "the blocked request answered before it was let go"
            gaps = [b - a for a, b in zip([t0, *during], during, strict=False)]
            print(
                f"while a query hung: {len(during)} heartbeats in {window_s:.1f} s (every {HEARTBEAT_S} s), "
                f"longest gap {max(gaps, default=float('nan')):.3f} s; /api/dives in {other_s * 1000:.0f} ms"
                f" ({pace})"
            )
            assert len(during) >= 10, f"{len(during)} heartbeats in {window_s:.1f} s while a query hung"
            assert max(gaps) < window_s / 2, (max(gaps), str(pace))

            release.set()
            requester.join(15)
            response = answer["response"]
            assert response.status_code == 200
            assert set(response.json()) == {
                "depth",
                "depth_by_module",
                "frames",
                "frame_step",
                "alarms",
                "clocks",
            }
    store.close()
