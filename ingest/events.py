"""The ingest's event bus: every new result is stored in the event log and published to subscribers.

Events are `camcal.core.events.Event`s. Stored kinds get the id of their
row in the ``events`` table: a subscriber that sees a jump in ids fetches
what it missed from the store. Transient kinds (health, decimated sensor
samples, attitude) carry no id and may be lost without harm. Published over
ZeroMQ PUB as ``[kind, json]`` by `EventPublisher`: plaintext on loopback,
CURVE beyond it, where only holders of the ship's secret key may subscribe
(`camcal.core.eventport`).
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path
from typing import Any

import zmq

from camcal.core.eventport import EVENTS_ZAP_DOMAIN, HANDSHAKE_MS, port_keys, use_curve
from camcal.core.events import Event, EventKind, StoredPayload
from camcal.core.ratelog import RateLimitedLog
from camcal.core.wire.keys import fingerprint, z85_of
from storage.store import Store

log = logging.getLogger("camcal.ingest")


class EventBus:
    """Collects events during a store-thread batch; `flush` persists and publishes them."""

    def __init__(self, store: Store, pub: Any | None) -> None:
        self.store = store
        self.pub = pub
        self._pending: list[Event] = []
        self.published = 0

    def emit(
        self,
        kind: EventKind,
        payload: StoredPayload,
        *,
        module: str | None = None,
        dive_id: int | None = None,
    ) -> None:
        """A stored event, written at the next `flush` (or by `take` into a transaction of the caller)."""
        self._pending.append(Event(kind, dict(payload), time.time(), module, dive_id))

    def transient(self, kind: EventKind, payload: dict[str, Any], *, module: str | None = None) -> None:
        """An event that is published only (health, sensors, attitude)."""
        if self.pub is not None:
            self._send(Event(kind, dict(payload), time.time(), module))

    def take(self) -> list[Event]:
        """The events emitted since the last flush, for a caller that stores them in its own transaction
        (then `published_stored` publishes them)."""
        events, self._pending = self._pending, []
        return events

    def flush(self) -> list[int]:
        """Store the pending events (one transaction) and publish them."""
        events = self.take()
        if not events:
            return []
        ids = self.store.add_events(events)
        self.published_stored(events)
        return ids

    def published_stored(self, events: list[Event]) -> None:
        """Publish events the store has already written (with their ``id``), e.g. with their frames."""
        for e in events:
            self._send(e)

    def _send(self, event: Event) -> None:
        if self.pub is None:
            return
        try:
            self.pub.send_multipart([event.kind.encode(), event.to_json()], flags=zmq.NOBLOCK)
            self.published += 1
        except zmq.Again:  # a PUB never blocks; slow subscribers lose messages, not the ingest
            pass


class EventPublisher:
    """The ingest's PUB socket on the events port (`camcal.core.eventport` says when it is CURVE).

    With CURVE it has a ZeroMQ context of its own, whose ZAP handler (bound before the socket,
    so no handshake passes unasked; answered on a thread of its own) lets in the ship's own key
    and refuses every other, each refused source logged at most once every ten seconds.
    """

    def __init__(
        self, endpoint: str, *, ctx: zmq.Context[Any], keys_dir: Path | None, curve: bool | None = None
    ) -> None:
        self.curve = use_curve(endpoint, curve)
        self.refused = 0
        self._ctx: zmq.Context[Any] | None = None
        self._zap: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        keys = port_keys(endpoint, keys_dir) if self.curve else None
        if keys is not None:
            self._ctx = ctx = zmq.Context()
            self._allowed = keys.public
            self._warn = RateLimitedLog(log)
            self._zap = ctx.socket(zmq.ROUTER)
            self._zap.setsockopt(zmq.LINGER, 0)
            self._zap.bind("inproc://zeromq.zap.01")
            self._thread = threading.Thread(target=self._answer_zap, name="events-zap", daemon=True)
            self._thread.start()
        self.socket = ctx.socket(zmq.PUB)
        if keys is not None:
            self.socket.setsockopt(zmq.CURVE_SERVER, 1)
            self.socket.setsockopt(zmq.CURVE_PUBLICKEY, keys.public)
            self.socket.setsockopt(zmq.CURVE_SECRETKEY, keys.secret)
            self.socket.setsockopt(zmq.ZAP_DOMAIN, EVENTS_ZAP_DOMAIN)
            self.socket.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_MS)
        self.socket.setsockopt(zmq.SNDHWM, 10000)
        self.socket.setsockopt(zmq.LINGER, 0)
        try:
            self.socket.bind(endpoint)
        except zmq.ZMQError:
            self.close()
            raise
        self.endpoint = self.socket.getsockopt(zmq.LAST_ENDPOINT).decode()

    def _answer_zap(self) -> None:
        while not self._stop.is_set():
            if not self._zap.poll(200):
                continue
            req = self._zap.recv_multipart()
            # [peer, "", version, request id, domain, address, identity, mechanism, credentials...]
            if len(req) < 8:
                continue
            ok = (
                req[4] == EVENTS_ZAP_DOMAIN
                and req[7] == b"CURVE"
                and len(req) >= 9
                and len(req[8]) == 32
                and z85_of(req[8]) == self._allowed
            )
            if not ok:
                self.refused += 1
                address = req[5].decode(errors="replace") or "an unknown address"
                key = fingerprint(z85_of(req[8])) if len(req) >= 9 and len(req[8]) == 32 else "no key"
                self._warn(
                    logging.WARNING,
                    f"events:{address}",
                    "refused a subscriber of the events port from %s (%s): only the ship's key may listen",
                    address,
                    key,
                )
            status, text = (b"200", b"OK") if ok else (b"400", b"not the ship's key")
            self._zap.send_multipart([req[0], b"", b"1.0", req[3], status, text, b"", b""])

    def close(self) -> None:
        """Close the socket (and, with CURVE, its ZAP handler and context)."""
        self._stop.set()
        sock = getattr(self, "socket", None)
        if sock is not None:
            sock.close(0)
        if self._thread is not None:
            self._thread.join(2)
        if self._zap is not None:
            self._zap.close(0)
        if self._ctx is not None:
            self._ctx.term()
