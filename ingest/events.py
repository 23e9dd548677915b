"""The ingest's event bus: every new result is stored in the event log and published to subscribers.

Events are `camcal.core.events.Event`s. Stored kinds get the id of their
row in the ``events`` table: a subscriber that sees a jump in ids fetches
what it missed from the store. Transient kinds (health, decimated sensor
samples, attitude) carry no id and may be lost without harm. Published over
ZeroMQ PUB as ``[kind, json]``.
"""

from __future__ import annotations

import time
from typing import Any

import zmq

from camcal.core.events import Event, EventKind, StoredPayload
from storage.store import Store


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
