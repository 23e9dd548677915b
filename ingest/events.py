"""Events: every new result is stored in the event log and published to subscribers.

Persistent events get the id of their row in the ``events`` table: a
subscriber that sees a jump in ids fetches what it missed from the store.
Transient events (health, decimated sensor samples) carry no id and may be
lost without harm. Published over ZeroMQ PUB as ``[kind, json]``.
"""

from __future__ import annotations

import json
import time
from typing import Any

import zmq

from storage.jsonsafe import finite_json
from storage.store import Store


def event_json(
    event_id: int | None,
    kind: str,
    t_unix_s: float,
    module: str | None,
    dive_id: int | None,
    payload: dict[str, Any],
) -> bytes:
    return json.dumps(
        {
            "id": event_id,
            "kind": kind,
            "t": t_unix_s,
            "module": module,
            "dive_id": dive_id,
            "payload": finite_json(payload),
        },
        separators=(",", ":"),
        default=str,
        allow_nan=False,
    ).encode()


class EventBus:
    """Collects events during a store-thread batch; `flush` persists and publishes them."""

    def __init__(self, store: Store, pub: Any | None) -> None:
        self.store = store
        self.pub = pub
        self._pending: list[dict[str, Any]] = []
        self.published = 0

    def emit(
        self, kind: str, payload: dict[str, Any], *, module: str | None = None, dive_id: int | None = None
    ) -> None:
        self._pending.append(
            {
                "kind": kind,
                "payload": payload,
                "module_id": module,
                "dive_id": dive_id,
                "t_unix_s": time.time(),
            }
        )

    def transient(self, kind: str, payload: dict[str, Any], *, module: str | None = None) -> None:
        if self.pub is not None:
            self._send(kind, event_json(None, kind, time.time(), module, None, payload))

    def flush(self) -> list[int]:
        if not self._pending:
            return []
        events, self._pending = self._pending, []
        ids = self.store.add_events(events)
        if self.pub is not None:
            for eid, e in zip(ids, events, strict=True):
                self._send(
                    e["kind"],
                    event_json(eid, e["kind"], e["t_unix_s"], e["module_id"], e["dive_id"], e["payload"]),
                )
        return ids

    def published_stored(self, events: list[dict[str, Any]]) -> None:
        """Publish events the store has already written (with their ``id``), e.g. with their frames."""
        for e in events:
            self._send(
                e["kind"],
                event_json(e["id"], e["kind"], e["t_unix_s"], e["module_id"], e["dive_id"], e["payload"]),
            )

    def _send(self, kind: str, body: bytes) -> None:
        if self.pub is None:
            return
        try:
            self.pub.send_multipart([kind.encode(), body], flags=zmq.NOBLOCK)
            self.published += 1
        except zmq.Again:  # a PUB never blocks; slow subscribers lose messages, not the ingest
            pass
