"""One dashboard server following several ingests (each serving some modules, one database)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq
from fastapi.testclient import TestClient

from camcal.core.events import Event, EventKind
from server.app import create_app
from server.relay import LiveHub
from server.settings import ServerSettings
from storage.store import Store


@pytest.fixture
def publishers() -> Iterator[list[tuple[zmq.Socket, str]]]:
    """Two PUB sockets standing in for two ingests' event publishers, on real TCP ports."""
    socks = []
    for _ in range(2):
        pub = zmq.Context.instance().socket(zmq.PUB)
        pub.setsockopt(zmq.LINGER, 0)
        pub.bind("tcp://127.0.0.1:*")
        socks.append((pub, pub.getsockopt(zmq.LAST_ENDPOINT).decode()))
    yield socks
    for pub, _ in socks:
        pub.close(0)


def beat(pub: zmq.Socket, ingest_id: str, module: str, stored: int) -> None:
    payload = {
        "ingest_id": ingest_id,
        "modules": {
            module: {
                "link": "up",
                "last_packet_age_s": 0.1,
                "frames_per_s": 2.0,
                "schedule": None,
                "boot": "b1",
            }
        },
        "queues": {"store": 1, "analysis_backlog": 2},
        "analysis_ready": module == "A",  # B's analysis processes still starting
        "counters": {"frames_stored": stored},
        "served_modules": [module],
        "disk_free_gb": 100.0 if module == "A" else 40.0,
        "latency_p95_s": 0.1 if module == "A" else 0.3,
    }
    pub.send_multipart([b"health", Event(EventKind.HEALTH, payload, time.time(), None, 1).to_json()])


def test_modules_of_every_ingest_are_shown_and_a_silent_one_degrades_the_status(
    tmp_path: Path, publishers: list[tuple[zmq.Socket, str]]
) -> None:
    store = Store.open(tmp_path / "data")
    for module in ("A", "B"):
        store.touch_module(module)
    store.close()
    (pub_a, ep_a), (pub_b, ep_b) = publishers
    settings = ServerSettings(data_dir=tmp_path / "data", events=f"{ep_a}, {ep_b}", stale_after_s=1.5)
    app = create_app(settings)
    with TestClient(app) as client:

        def health(until) -> dict:
            deadline = time.monotonic() + 15
            while time.monotonic() < deadline:
                beat(pub_a, "ship-1 tcp://*:5555 (A)", "A", 10)
                if until_b_beats[0]:
                    beat(pub_b, "ship-2 tcp://*:5555 (B)", "B", 7)
                h = client.get("/api/health").json()
                if until(h):
                    return h
                time.sleep(0.2)
            raise AssertionError(f"never: {h}")

        until_b_beats = [True]
        both = health(lambda h: len(h["ingest"]["ingests"]) == 2 and h["status"] == "ok")
        assert both["modules"]["A"]["link"] == both["modules"]["B"]["link"] == "up"
        assert both["counters"]["frames_stored"] == 17  # added up over the ingests
        assert both["queues"] == {"store": 2, "analysis_backlog": 4}
        assert both["analysis_ready"] is False  # ready only when every ingest's analysis is
        metrics = client.get("/metrics").text  # the worst latency of the two
        assert 'camcal_result_latency_seconds{quantile="0.95"} 0.3' in metrics

        until_b_beats[0] = False  # ingest 2 goes silent
        one = health(lambda h: h["status"] == "degraded")
        states = {i["id"]: i["up"] for i in one["ingest"]["ingests"]}
        assert states == {"ship-1 tcp://*:5555 (A)": True, "ship-2 tcp://*:5555 (B)": False}
        assert one["ingest"]["up"] is False
        assert one["modules"]["A"]["link"] == "up"  # the live ingest's modules stay live
        assert one["modules"].get("B", {"link": "unknown"})["link"] == "unknown"
        assert one["counters"]["frames_stored"] == 10


def test_an_event_committed_after_a_later_id_is_still_relayed_once(tmp_path: Path) -> None:
    """Two ingests on PostgreSQL: id 2 is taken before id 3 but committed after it. The relay
    must pass 2 on when it comes, and never twice."""
    store = Store.open(tmp_path / "data")
    hub = LiveHub(store, None)
    posted: list[int | None] = []
    hub._post = lambda event: posted.append(event.id)  # what would reach the browsers
    start = hub.last_event_id
    (first,) = store.add_events([Event(EventKind.LINK, {}, 1.0, "A")])
    hub._incoming(Event(EventKind.LINK, {}, 1.0, "A", id=first))
    late, later = (
        first + 1,
        first + 2,
    )  # "later" is committed and published first; "late" not yet in the store
    hub._incoming(Event(EventKind.LINK, {}, 1.0, "A", id=later))
    hub._incoming(Event(EventKind.LINK, {}, 1.0, "A", id=late))
    hub._incoming(Event(EventKind.LINK, {}, 1.0, "A", id=later))  # duplicates: a resend, a read-back
    hub._incoming(Event(EventKind.LINK, {}, 1.0, "A", id=late))
    hub._incoming(Event(EventKind.LINK, {}, 1.0, "A", id=start))  # from before the server started
    assert posted == [first, later, late]
    store.close()
