"""Per-module sequence numbers: duplicates, order, and the gaps a broken link leaves."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class _BootSeqs:
    upto: int = 0  # every seq <= upto has arrived
    ahead: set[int] = field(default_factory=set)
    max_seen: int = 0


class SeqTracker:
    """Tracks which sequence numbers of each (module, boot) have arrived.

    Frames and sensor batches share one sequence per boot, starting at 1. A
    jump past the highest number seen so far opens a gap; arrivals inside it
    (resends) fill it.
    """

    def __init__(self) -> None:
        self._boots: dict[tuple[str, str], _BootSeqs] = {}

    def known(self, module: str, boot: str) -> bool:
        return (module, boot) in self._boots

    def seed(self, module: str, boot: str, seqs: set[int]) -> None:
        """Start from what the store already holds (after a restart)."""
        st = _BootSeqs()
        for q in sorted(seqs):
            self._add(st, q)
        self._boots[(module, boot)] = st

    def add(self, module: str, boot: str, seq: int) -> tuple[int, int] | None:
        """Record an arrival; returns a newly opened gap ``(first, last)`` or None."""
        st = self._boots.setdefault((module, boot), _BootSeqs())
        return self._add(st, seq)

    @staticmethod
    def _add(st: _BootSeqs, seq: int) -> tuple[int, int] | None:
        gap = None
        if seq > st.max_seen + 1:
            gap = (st.max_seen + 1, seq - 1)
        st.max_seen = max(st.max_seen, seq)
        if seq == st.upto + 1:
            st.upto = seq
            while st.upto + 1 in st.ahead:
                st.upto += 1
                st.ahead.discard(st.upto)
        elif seq > st.upto:
            st.ahead.add(seq)
        return gap

    def expect(self, module: str, boot: str, last_seq: int) -> tuple[int, int] | None:
        """The module says it produced up to ``last_seq``: returns the numbers above the highest
        seen as a newly opened gap ``(first, last)``, or None; later arrivals in it fill it."""
        st = self._boots.setdefault((module, boot), _BootSeqs())
        if last_seq <= st.max_seen:
            return None
        gap = (st.max_seen + 1, last_seq)
        st.max_seen = last_seq
        return gap

    def missing(self, module: str, boot: str) -> list[tuple[int, int]]:
        """Ranges not yet arrived below the highest number seen."""
        st = self._boots.get((module, boot))
        if st is None:
            return []
        out = []
        start = None
        for q in range(st.upto + 1, st.max_seen + 1):
            if q not in st.ahead:
                if start is None:
                    start = q
            elif start is not None:
                out.append((start, q - 1))
                start = None
        if start is not None:
            out.append((start, st.max_seen))
        return out

    def arrived(self, module: str, boot: str) -> set[int]:
        st = self._boots.get((module, boot))
        if st is None:
            return set()
        return set(range(1, st.upto + 1)) | st.ahead
