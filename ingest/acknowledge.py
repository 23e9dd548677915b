"""Acknowledge: every answer to a module, from whichever stage decided it, goes out through here.

The checking and storing threads decide a data message's fate (`ack` once
it is committed, `refuse` with a reason); this stage makes the answer
(acknowledgements as ranges per boot), counts it, and hands it to the
receiving thread, the only owner of the ROUTER socket, over an inproc
socket of the calling thread. With the answer goes the list of data
messages it settles, so that the receiving thread knows how many of the
module's messages are still unanswered (its window, `ingest.receive`).
Commands to the modules go the same way (`send`).
"""

from __future__ import annotations

import json
import threading
from collections import defaultdict
from collections.abc import Iterable
from typing import Any

import zmq

from camcal.core import wire
from ingest.counters import Counters
from ingest.messages import Key, nack


class Acknowledge:
    """Answers to modules, sent through the receiving thread (see the module docstring)."""

    def __init__(self, ctx: zmq.Context[Any], endpoint: str, counters: Counters, window: Any) -> None:
        self.ctx = ctx
        self.endpoint = endpoint
        self.counters = counters
        self.window = window  # () -> the credit to give with each acknowledgement
        self._local = threading.local()
        self._sockets: list[Any] = []
        self._lock = threading.Lock()

    def _push(self) -> Any:
        sock = getattr(self._local, "sock", None)
        if sock is None:
            sock = self.ctx.socket(zmq.PUSH)
            sock.setsockopt(zmq.LINGER, 1000)
            sock.connect(self.endpoint)
            self._local.sock = sock
            with self._lock:
                self._sockets.append(sock)
        return sock

    def send(self, module: str, msg: Any, settles: Iterable[Key] = ()) -> None:
        """Hand a message for ``module`` to the receiving thread ; ``settles``: what it answers."""
        keys = json.dumps([[b, q] for _, b, q in settles]).encode()
        self._push().send_multipart([module.encode(), keys, *wire.encode(msg)])

    def ack(self, keys: Iterable[Key]) -> None:
        """Acknowledge committed data messages (new or resent), as ranges per boot, one answer per module."""
        per_module: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(list))
        for module, boot, seq in keys:
            per_module[module][boot].append(seq)
        for module, boots in per_module.items():
            ranges: list[tuple[str, int, int]] = []
            settled: list[Key] = []
            for boot, seqs in boots.items():
                seqs = sorted(set(seqs))
                settled += [(module, boot, q) for q in seqs]
                start = prev = seqs[0]
                for q in seqs[1:]:
                    if q != prev + 1:
                        ranges.append((boot, start, prev))
                        start = q
                    prev = q
                ranges.append((boot, start, prev))
            ack = wire.Ack(module="ship", ranges=tuple(ranges), window=self.window(module))
            self.send(module, ack, settled)
            self.counters.inc("acks_sent")

    def refuse(self, msg: Any, reason: str, detail: str, *, malformed: bool = False) -> None:
        """Refuse a decoded message (a data message by its boot and seq) with a ``nack``, and count it."""
        self.counters.refuse(reason, malformed=malformed)
        ref = wire.message_ref(msg)
        settles = [(msg.module, ref["boot"], ref["seq"])] if ref.get("seq") is not None else []
        self.send(msg.module, nack(reason, detail, ref), settles)

    def close(self) -> None:
        with self._lock:
            for sock in self._sockets:
                sock.close()
            self._sockets.clear()
