"""The live hub: events from the ingest, fanned out to every browser.

A thread subscribes to the ingest's event publisher (one socket per ingest: each is plaintext on
loopback and CURVE, with the ship's key pair, beyond it; `camcal.core.eventport`). Stored events carry
their id in the event log; when ids jump (the ZeroMQ subscriber lost some),
the hub reads the missing ones from the database, so nothing persistent is
lost. Each browser has a bounded queue: when a browser is slow, thumbnails
and sensor samples are dropped for it first, the ingest never waits, and the
browser is told what it missed (and to reload its snapshot if something that
matters was dropped).
"""

from __future__ import annotations

import asyncio
import json
import logging
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zmq

from camcal.core.eventport import port_keys, subscriber, use_curve
from camcal.core.events import Event, EventError, EventKind
from camcal.core.settings import endpoint_list
from ingest.derived import dive_phase
from server.saturation import SaturationByDesign
from storage import queries
from storage.store import Store

log = logging.getLogger("camcal.server.live")

#: Key of an event's JSON text, made once in `LiveHub.deliver` (see `encode_for`).
ENCODED = "_json"

#: Kinds a slow browser can do without (the next one replaces them).
DROPPABLE = frozenset({"sensors", "attitude", "health", "frame", "result"})


@dataclass(eq=False)
class Client:
    """One browser's WebSocket: its queue, its sequence and what it missed."""

    queue: asyncio.Queue[dict[str, Any]]
    seq: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    resync: bool = False
    batch: bool = False
    address: str = ""

    def next_seq(self) -> int:
        self.seq += 1
        return self.seq


def encode_for(message: dict[str, Any], seq: int) -> str:
    """The JSON text of ``message`` with a connection's ``seq``, reusing the text made once per event."""
    body = message.get(ENCODED)
    if body is None:
        return json.dumps({**message, "seq": seq}, default=str)
    return f'{{"seq":{seq},{body[1:]}'


#: Event ids remembered as delivered (duplicates and late commits are told apart among them).
SEEN_IDS = 20_000


class LiveHub:
    """Receives the ingest's events and delivers them to the connected browsers."""

    def __init__(
        self,
        store: Store,
        events_endpoint: str | None,
        *,
        client_queue: int = 256,
        ctx: zmq.Context[Any] | None = None,
        station_depth_m: float | None = None,
        saturation: SaturationByDesign | None = None,
        keys_dir: Path | None = None,
        events_curve: bool | None = None,
    ) -> None:
        self.store = store
        self.keys_dir, self.events_curve = keys_dir, events_curve
        #: Labels each saturated frame's result ``by_design`` or not (`server.saturation`).
        self.saturation = saturation
        # Several ingests (one per group of modules, sharing the database): their publishers,
        # comma-separated. A SUB socket connects to each; heartbeats are kept per ingest.
        self.endpoints = endpoint_list(events_endpoint)
        for endpoint in self.endpoints:  # beyond loopback without the ship's keys: say so at start
            if use_curve(endpoint, events_curve):
                port_keys(endpoint, keys_dir)
        self.client_queue = client_queue
        self.ctx = ctx or zmq.Context.instance()
        self.clients: set[Client] = set()
        self._heartbeats: dict[str, tuple[dict[str, Any], float]] = {}  # ingest id -> (health, when)
        self.sensors: dict[str, dict[str, Any]] = {}
        self.attitude: dict[str, dict[str, Any]] = {}
        self.depths: dict[str, deque[tuple[float, float]]] = {}
        self.deepest_m: dict[str, float] = {}  # over the whole run, not just the recent samples
        self.station_depth_m = station_depth_m
        self.last_event_id = store.call(queries.last_event_id)  # the highest id delivered
        # Ids delivered recently, and below them the floor under which every id counts as delivered:
        # with several ingests on PostgreSQL, ids are taken in one order and committed in another,
        # so an id below the highest may still be new.
        self._seen: set[int] = set()
        self._seen_order: deque[int] = deque()
        self._floor = self.last_event_id
        self.received = 0
        self.recovered = 0
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------ lifecycle
    def start(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        if self.endpoints:
            self._thread = threading.Thread(target=self._run, name="live-hub", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)

    def _run(self) -> None:
        subs = [
            subscriber(self.ctx, e, keys_dir=self.keys_dir, curve=self.events_curve, rcvhwm=100000)
            for e in self.endpoints
        ]
        poller = zmq.Poller()
        for sub in subs:
            poller.register(sub, zmq.POLLIN)
        try:
            while not self._stop.is_set():
                self._refresh_saturation()
                for sub, _ in poller.poll(200):
                    self._drain(sub)
        finally:
            for sub in subs:
                sub.close(0)

    def _drain(self, sub: Any) -> None:
        while True:
            try:
                _kind, body = sub.recv_multipart(zmq.NOBLOCK)
            except zmq.Again:
                return
            except ValueError:
                continue
            try:
                event = Event.from_json(body)
            except EventError:
                continue
            self._incoming(event)

    def _refresh_saturation(self) -> None:
        """Renew the prediction of saturated settings now and then (a read: never on the event loop)."""
        if self.saturation is None:
            return
        try:
            self.saturation.refresh()
        except Exception as exc:  # the database is down: the last prediction stays, said once a while
            log.warning("cannot renew the prediction of saturated settings: %s", exc)

    def _incoming(self, event: Event) -> None:
        """In the hub thread: recover missed stored events, then hand over to the loop."""
        self.received += 1
        eid = event.id
        if eid is not None:
            if eid <= self._floor or eid in self._seen:
                return
            if eid > self.last_event_id + 1:
                missed = self.store.call(
                    queries.events_after, self.last_event_id, eid - self.last_event_id - 1
                )
                for m in missed:
                    if m.id is not None and m.id < eid and m.id not in self._seen:
                        self.recovered += 1
                        self._mark(m.id)
                        self._post(m)
            self._mark(eid)
        self._post(event)

    def _mark(self, eid: int) -> None:
        self._seen.add(eid)
        self._seen_order.append(eid)
        self.last_event_id = max(self.last_event_id, eid)
        while len(self._seen_order) > SEEN_IDS:
            old = self._seen_order.popleft()
            self._seen.discard(old)
            self._floor = max(self._floor, old)

    def _post(self, event: Event) -> None:
        if self._loop is not None and not self._loop.is_closed():
            self._loop.call_soon_threadsafe(self.deliver, event)

    def deliver_threadsafe(self, event: Event) -> None:
        """`deliver` from any thread (a plain ``def`` route runs in the threadpool): on the loop."""
        self._post(event)

    # ------------------------------------------------------------ delivery (event loop)
    def deliver(self, event: Event) -> None:
        kind, module, payload = event.kind, event.module, event.payload
        if kind == EventKind.HEALTH:
            self.record_health(payload)
        elif kind == EventKind.SENSORS and module:
            self.sensors[module] = payload
            if payload.get("depth_m") is not None and payload.get("t_unix_s") is not None:
                hist = self.depths.setdefault(module, deque(maxlen=600))
                hist.append((payload["t_unix_s"], payload["depth_m"]))
                self.deepest_m[module] = max(self.deepest_m.get(module, 0.0), float(payload["depth_m"]))
        elif kind == EventKind.ATTITUDE and module:
            self.attitude[module] = payload
        elif (
            kind == EventKind.RESULT and payload.get("reason") == "saturated" and self.saturation is not None
        ):
            s = self.saturation
            expected = s.expected(
                module, payload.get("wavelength_nm"), payload.get("exposure_s"), payload.get("gain_db")
            )
            payload = {**payload, "by_design": expected}
        message = {
            "type": "event",
            "kind": str(kind),
            "event_id": event.id,
            "module": module,
            "t": event.t,
            "payload": payload,
        }
        if self.clients:
            # Serialised once for every browser; each connection only prepends its own seq.
            message[ENCODED] = json.dumps(message, default=str)
        for client in list(self.clients):
            self._offer(client, message)

    def _offer(self, client: Client, message: dict[str, Any]) -> None:
        kind = message["kind"]
        q = client.queue
        if kind in DROPPABLE and q.qsize() >= q.maxsize // 2:
            client.dropped[kind] += 1
            return
        if q.full():
            client.dropped[kind] += 1
            client.resync = True
            return
        q.put_nowait(message)

    def register(self, address: str = "") -> Client:
        client = Client(asyncio.Queue(self.client_queue), address=address)
        self.clients.add(client)
        return client

    def connections_of(self, address: str) -> int:
        """Live connections of one client address."""
        return sum(1 for c in self.clients if c.address == address)

    def unregister(self, client: Client) -> None:
        self.clients.discard(client)

    # ------------------------------------------------------------ state
    def record_health(self, payload: dict[str, Any], at: float | None = None) -> None:
        """An ingest's heartbeat (its ``ingest_id`` tells several ingests apart)."""
        key = str(payload.get("ingest_id") or "ingest")
        self._heartbeats[key] = (payload, time.time() if at is None else at)

    def live_health(self, stale_after_s: float) -> dict[str, Any] | None:
        """The heartbeats of the ingests heard from within ``stale_after_s``, as one; None if none."""
        now = time.time()
        fresh = [p for p, at in self._heartbeats.values() if now - at <= stale_after_s]
        return merge_health(fresh) if fresh else None

    def ingest_state(self, stale_after_s: float) -> dict[str, Any]:
        """Up when every ingest heard from is still beating: a silent one is the deck's business."""
        now = time.time()
        ages = {key: now - at for key, (_, at) in sorted(self._heartbeats.items())}
        return {
            "connected": bool(self.endpoints),
            "up": bool(ages) and all(age <= stale_after_s for age in ages.values()),
            "age_s": round(max(ages.values()), 2) if ages else None,
            "ingests": [
                {"id": key, "up": age <= stale_after_s, "age_s": round(age, 2)} for key, age in ages.items()
            ],
        }

    def phase(self, module: str) -> str | None:
        hist = self.depths.get(module)
        if not hist:
            return None
        t = [x[0] for x in hist]
        d = [x[1] for x in hist]
        return dive_phase(t, d, self.deepest_m.get(module), self.station_depth_m)


def merge_health(payloads: list[dict[str, Any]]) -> dict[str, Any]:
    """Several ingests' heartbeats as one: modules side by side, counts and queues added up,
    the least free disk and the worst latency."""
    if len(payloads) == 1:
        return payloads[0]
    out: dict[str, Any] = {"ingest_id": ", ".join(str(p.get("ingest_id")) for p in payloads)}
    out["modules"] = {m: h for p in payloads for m, h in (p.get("modules") or {}).items()}
    for key in ("queues", "counters", "malformed", "nacked", "refused"):
        total: dict[str, float] = {}
        for p in payloads:
            for k, v in (p.get(key) or {}).items():
                if isinstance(v, int | float):
                    total[k] = total.get(k, 0) + v
        out[key] = total
    out["served_modules"] = [m for p in payloads for m in p.get("served_modules") or []]
    refused = [p["refused_connections"] for p in payloads if p.get("refused_connections")]
    out["refused_connections"] = (
        {
            "total": sum(r.get("total", 0) for r in refused),
            "last_minute": sum(r.get("last_minute", 0) for r in refused),
            "sources": sorted(
                (s for r in refused for s in r.get("sources", [])), key=lambda s: -s.get("last_unix_s", 0)
            )[:16],
        }
        if refused
        else None
    )
    security = {p.get("link_security") for p in payloads}
    out["link_security"] = "plaintext" if "plaintext" in security else next(iter(security), None)
    out["analysis_ready"] = all(p.get("analysis_ready") is not False for p in payloads)
    out["dive"] = payloads[0].get("dive")
    out["window"] = payloads[0].get("window")
    disk = [p["disk_free_gb"] for p in payloads if p.get("disk_free_gb") is not None]
    out["disk_free_gb"] = min(disk) if disk else None
    for key in ("latency_p50_s", "latency_p95_s"):
        values = [p[key] for p in payloads if p.get(key) is not None]
        out[key] = max(values) if values else None
    return out
