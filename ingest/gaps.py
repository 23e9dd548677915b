"""Gaps in a module's sequence numbers: opened by jumps and lost links, filled by resends and imports."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from camcal.core.events import EventKind, GapPayload
from ingest.events import EventBus
from ingest.seqtrack import SeqTracker
from storage import queries
from storage.store import Store


class Gaps:
    def __init__(self, store: Store, events: EventBus, dive_id: int, serves: Callable[[str], bool]) -> None:
        self.store = store
        self.events = events
        self.dive_id = dive_id
        self.seqs = SeqTracker()
        self.gappy: set[tuple[str, str]] = {
            (g.module_id, g.boot) for g in self.store.call(queries.open_gaps) if serves(g.module_id)
        }

    def _known(self, module: str, boot: str) -> None:
        if not self.seqs.known(module, boot):
            self.seqs.seed(module, boot, self.store.call(queries.known_seqs, module, boot))

    def arrived(self, msgs: Iterable[Any]) -> None:
        """Committed messages (new or resent): record jumps as gaps, close gaps they fill."""
        touched = set()
        for m in msgs:
            self._known(m.module, m.boot)
            gap = self.seqs.add(m.module, m.boot, m.seq)
            touched.add((m.module, m.boot))
            if gap:
                self._open(m.module, m.boot, gap, None)
        for module, boot in touched & self.gappy:
            covers = lambda a, b, m=module, bt=boot: self.seqs.covers(m, bt, a, b)  # noqa: E731
            for gid in self.store.fill_gaps(module, boot, covers):
                self.events.emit(
                    EventKind.GAP_FILLED,
                    {"gap_id": gid, "boot": boot},
                    module=module,
                    dive_id=self.dive_id,
                )
            if not self.seqs.missing(module, boot):
                self.gappy.discard((module, boot))

    def link_down(self, module: str, boot: str, last_seq: int) -> None:
        """Record as a gap what the module said it had produced but the ship does not have.

        Everything received before the link went down is committed by now
        (the notice queued behind it), so numbers above the highest stored
        one, up to the module's ``last_seq``, are in its outbox only: after a
        link lost for good they arrive only by `camcal import`, and the open
        gap says so. A reconnect that resends them fills it.
        """
        self._known(module, boot)
        gap = self.seqs.expect(module, boot, last_seq)
        if gap is not None:
            self._open(module, boot, gap, "link_lost")

    def _open(self, module: str, boot: str, gap: tuple[int, int], reason: str | None) -> None:
        self.store.record_gap(module, boot, *gap)
        self.gappy.add((module, boot))
        payload: GapPayload = {"boot": boot, "first_seq": gap[0], "last_seq": gap[1]}
        if reason:
            payload["reason"] = reason
        self.events.emit(EventKind.GAP, payload, module=module, dive_id=self.dive_id)
