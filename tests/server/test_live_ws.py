"""WS /ws/live: snapshot first, sequenced events, slow clients, recovery of missed stored events."""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq
from fastapi.testclient import TestClient

from camcal.core.events import Event, EventKind
from server.app import create_app
from server.settings import ServerSettings
from storage.store import Store


@pytest.fixture
def publisher() -> Iterator[tuple[zmq.Socket, str]]:
    """A PUB socket standing in for the ingest's events, and its endpoint; closed even when a test fails."""
    pub = zmq.Context.instance().socket(zmq.PUB)
    pub.setsockopt(zmq.LINGER, 0)
    pub.bind("tcp://127.0.0.1:*")
    yield pub, pub.getsockopt(zmq.LAST_ENDPOINT).decode()
    pub.close(0)


def publish(
    pub: zmq.Socket, kind: str, payload: dict, event_id: int | None = None, module: str | None = "A"
) -> None:
    event = Event(EventKind(kind), payload, time.time(), module, 1, event_id)
    pub.send_multipart([kind.encode(), event.to_json()])


def wait_subscribed(ws, pub) -> None:
    """PUB/SUB joins asynchronously: publish health until it comes through."""
    for _ in range(100):
        publish(pub, "health", {"modules": {}, "queues": {}})
        msg = ws.receive_json()
        if msg.get("kind") == "health":
            return
    raise AssertionError("the hub never subscribed")


def test_snapshot_then_sequenced_events(tmp_path: Path, publisher: tuple[zmq.Socket, str]) -> None:
    pub, endpoint = publisher
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=endpoint))
    with TestClient(app) as client, client.websocket_connect("/ws/live") as ws:
        first = ws.receive_json()
        assert first["type"] == "snapshot" and first["seq"] == 1
        assert {"modules", "attenuation", "alarms", "ingest", "dive"} <= set(first["data"])
        assert first["data"]["simulation_speed"] is None  # real modules: no "simulated dive" note
        wait_subscribed(ws, pub)
        publish(pub, "result", {"frame_id": 7, "status": "ok"})
        publish(pub, "sensors", {"t_unix_s": 1.0, "depth_m": 3400.0, "humidity_pct": 31.0})
        got = [ws.receive_json(), ws.receive_json()]
        assert [m["kind"] for m in got] == ["result", "sensors"]
        seqs = [m["seq"] for m in got]
        assert seqs == sorted(seqs) and seqs[1] == seqs[0] + 1
        ws.send_text(json.dumps({"type": "resync"}))
        again = ws.receive_json()
        assert again["type"] == "snapshot" and again["seq"] == seqs[1] + 1
        assert again["data"]["modules"] == {} or isinstance(again["data"]["modules"], dict)


def test_a_slow_browser_loses_droppable_events_first_and_is_told(
    tmp_path: Path, publisher: tuple[zmq.Socket, str]
) -> None:
    pub, endpoint = publisher
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=endpoint, client_queue=8))
    with TestClient(app) as client, client.websocket_connect("/ws/live") as ws:
        ws.receive_json()
        wait_subscribed(ws, pub)
        hub = app.state.hub
        # Fill this browser's queue while it does not read (the hub never waits for it).
        for i in range(200):
            publish(pub, "sensors", {"t_unix_s": float(i), "depth_m": 1.0})
        publish(pub, "alarm", {"state": "raised", "kind": "tilt", "severity": "MINOR"})
        deadline = time.time() + 5
        while time.time() < deadline and hub.received < 202:
            time.sleep(0.02)
        messages = []
        while True:
            m = ws.receive_json()
            messages.append(m)
            if m.get("kind") == "alarm":
                break
        missed = [m for m in messages if m["type"] == "missed"]
        dropped = sum(m["dropped"].get("sensors", 0) for m in missed)
        delivered = len([m for m in messages if m.get("kind") == "sensors"])
        # The queue holds 8: some had to go (how many depends on how fast the test client drains it) ...
        assert missed and dropped > 0
        assert dropped + delivered == 200  # ... and the browser knows exactly how many
        assert not any(m["resync"] for m in missed)  # only droppable events were lost
        seqs = [m["seq"] for m in messages]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))


def test_stored_events_lost_by_pubsub_are_read_back_from_the_store(
    tmp_path: Path, publisher: tuple[zmq.Socket, str]
) -> None:
    store = Store.open(tmp_path / "data", sqlite_synchronous="NORMAL")
    pub, endpoint = publisher
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=endpoint), store=store)
    with TestClient(app) as client, client.websocket_connect("/ws/live") as ws:
        ws.receive_json()
        wait_subscribed(ws, pub)
        ids = store.add_events(
            [Event(EventKind.LINK, {"state": s}, 1.0, "A") for s in ("down", "up", "down")]
        )
        # Only the last one is published: the two before it were "lost" on the way.
        publish(pub, "link", {"state": "down"}, event_id=ids[-1])
        got = [ws.receive_json() for _ in range(3)]
        assert [m["event_id"] for m in got] == ids
        assert [m["payload"]["state"] for m in got] == ["down", "up", "down"]
        assert app.state.hub.recovered == 2
    store.close()
