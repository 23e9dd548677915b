"""Check: the payload of every data message, a few milliseconds at a time, the modules in turn.

The receiving thread checked a message's header; this stage checks what it
carries (`wire.check_payload`: the checksum, a frame's image header, the rows
of a sensor batch) in steps of a few milliseconds. It works on one message
per module at a time and does one step of each in turn, so that a module's
frame is checked between two steps of another module's batch of 100 000 rows
instead of after it, and the receiving and storing threads get the
interpreter between steps.

A message that passes goes to the store's line of its module (`Checked`; a
sensor batch of more than `PART_ROWS` rows as parts the store commits one a
turn); one that fails is refused (`ingest.acknowledge`). The module's other
news (`Note`: links, heartbeats) passes through in order behind its data.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Generator
from typing import Any

from camcal.core import wire
from camcal.core.ratelog import RateLimitedLog
from ingest.acknowledge import Acknowledge
from ingest.fairness import FairQueue
from ingest.messages import PART_ROWS, Checked, DataIn, Note

log = logging.getLogger("camcal.ingest")


class Checker:
    """Runs in the ``ingest-check`` thread; see the module docstring."""

    def __init__(
        self,
        inq: FairQueue[DataIn | Note],
        outq: FairQueue[Checked | Note],
        acknowledge: Acknowledge,
        counters: Any,
    ) -> None:
        self.inq = inq
        self.outq = outq
        self.acknowledge = acknowledge
        self.counters = counters
        self.jobs: OrderedDict[str, tuple[DataIn, Generator[None, None, Any]]] = OrderedDict()
        self.warn = RateLimitedLog(log)

    def busy(self) -> int:
        """Messages being checked or waiting to be."""
        return len(self.jobs) + len(self.inq)

    def run(self, stop: threading.Event) -> None:
        while True:
            if not self.jobs and not self.inq.wait(0.05):
                if stop.is_set():
                    break
                continue
            for item in self.inq.take(per_module=1, skip=set(self.jobs)):
                if isinstance(item, Note):
                    self.outq.put(item.module, item)
                else:
                    self.jobs[item.module] = (item, wire.check_payload(item.msg, item.payload))
            for module in list(self.jobs):
                self._step(module)
            time.sleep(0)  # let the receiving and storing threads in between two rounds

    def _step(self, module: str) -> None:
        item, steps = self.jobs[module]
        try:
            next(steps)
            self.jobs.move_to_end(module)
            return
        except StopIteration as done:
            del self.jobs[module]
            self._passed(item, done.value)
        except wire.ProtocolError as exc:
            del self.jobs[module]
            self.warn(
                logging.WARNING,
                f"refused:{exc.kind}",
                "refused a message from %r: %s: %s",
                module,
                exc.kind,
                exc.detail,
            )
            self.acknowledge.refuse(item.msg, exc.kind, exc.detail, malformed=True)
        except Exception as exc:  # a fault of the ship's own code: answered, never a stop
            del self.jobs[module]
            self.counters.inc("handler_errors")
            self.warn(logging.ERROR, "check", "ingest: checking a message failed: %s", exc, exc_info=True)
            self.acknowledge.refuse(item.msg, "internal_error", f"the ship failed on this message: {exc}")

    def _passed(self, item: DataIn, payload: Any) -> None:
        msg = item.msg
        rows = len(payload) if msg.type == "sensors" else 0
        if rows <= PART_ROWS:
            self.outq.put(
                item.module,
                Checked(msg, payload, item.received_unix_s, item.received_mono, item.nbytes, item.clock),
            )
            return
        for first in range(0, rows, PART_ROWS):
            n = min(PART_ROWS, rows - first)
            part = Checked(
                msg,
                payload,
                item.received_unix_s,
                item.received_mono,
                item.nbytes * n // rows,
                item.clock,
                part=(first, n, rows),
            )
            self.outq.put(item.module, part)
