"""Per-module sequence numbers: duplicates, order, and the gaps a broken link leaves.

What has arrived is kept as sorted, disjoint ranges, so every operation
costs in proportion to the number of gaps, never to the size of a jump: a
module whose ``seq`` leaps to 2^63 - 1 opens one gap of that size, recorded
as one range.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, field


@dataclass
class _BootSeqs:
    starts: list[int] = field(default_factory=list)  # arrived ranges [starts[i], ends[i]], sorted, disjoint
    ends: list[int] = field(default_factory=list)
    max_seen: int = 0

    def add(self, seq: int) -> bool:
        """Record ``seq``; False if it had arrived already."""
        i = bisect.bisect_right(self.starts, seq) - 1  # the range starting at or before seq
        if i >= 0 and self.ends[i] >= seq:
            return False
        joins_left = i >= 0 and self.ends[i] == seq - 1
        joins_right = i + 1 < len(self.starts) and self.starts[i + 1] == seq + 1
        if joins_left and joins_right:
            self.ends[i] = self.ends[i + 1]
            del self.starts[i + 1], self.ends[i + 1]
        elif joins_left:
            self.ends[i] = seq
        elif joins_right:
            self.starts[i + 1] = seq
        else:
            self.starts.insert(i + 1, seq)
            self.ends.insert(i + 1, seq)
        return True

    def covers(self, first: int, last: int) -> bool:
        i = bisect.bisect_right(self.starts, first) - 1
        return i >= 0 and self.ends[i] >= last

    def missing(self) -> list[tuple[int, int]]:
        out, nxt = [], 1
        for a, b in zip(self.starts, self.ends, strict=True):
            if a > nxt:
                out.append((nxt, a - 1))
            nxt = b + 1
        if nxt <= self.max_seen:
            out.append((nxt, self.max_seen))
        return out


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
            st.add(q)
        st.max_seen = max(seqs, default=0)
        self._boots[(module, boot)] = st

    def add(self, module: str, boot: str, seq: int) -> tuple[int, int] | None:
        """Record an arrival; returns a newly opened gap ``(first, last)`` or None."""
        st = self._boots.setdefault((module, boot), _BootSeqs())
        gap = (st.max_seen + 1, seq - 1) if seq > st.max_seen + 1 else None
        st.max_seen = max(st.max_seen, seq)
        st.add(seq)
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
        return st.missing() if st is not None else []

    def covers(self, module: str, boot: str, first: int, last: int) -> bool:
        """Whether every number from ``first`` to ``last`` has arrived."""
        st = self._boots.get((module, boot))
        return st is not None and st.covers(first, last)

    def arrived_ranges(self, module: str, boot: str) -> list[tuple[int, int]]:
        st = self._boots.get((module, boot))
        return list(zip(st.starts, st.ends, strict=True)) if st is not None else []
