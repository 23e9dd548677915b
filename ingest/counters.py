"""The ingest's counters: messages received, stored and refused, by group and reason.

Counters come in groups: ``counters`` (messages received, stored,
acknowledged...), ``malformed`` (refused while decoding, by reason),
``nacked`` (every refusal, by reason: the malformed ones and those refused
later, such as conflicts) and ``refused`` (messages of modules this ingest
does not serve, by module). Totals are kept beside the groups so that
``counters["malformed"] == sum(malformed.values())`` and ``counters["nacked"]
== sum(nacked.values())`` always hold: both are changed together, under one
lock. The store keeps them, so a restart continues the counts instead of
zeroing them: the counts of stored messages in the very transaction that
stores them (`ingest.commit`), the rest once a second, and the ingest
publishes in its health the values it has just saved, so that what anyone
saw never goes backwards after a crash.
"""

from __future__ import annotations

import threading
from collections import Counter

GROUPS = ("counters", "malformed", "nacked", "refused")


class Counters:
    """Thread-safe counters of one ingest, in `GROUPS`."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._groups: dict[str, Counter[str]] = {g: Counter() for g in GROUPS}
        self._dirty = False

    def inc(self, name: str, n: int = 1) -> None:
        """Add to ``counters[name]``."""
        with self._lock:
            self._groups["counters"][name] += n
            self._dirty = True

    def refuse(self, reason: str, *, malformed: bool) -> None:
        """Count one refused message (and, if ``malformed``, one refused while decoding)."""
        with self._lock:
            c = self._groups["counters"]
            self._groups["nacked"][reason] += 1
            c["nacked"] += 1
            if malformed:
                self._groups["malformed"][reason] += 1
                c["malformed"] += 1
            self._dirty = True

    def not_served(self, module: str) -> int:
        """Count a message of a module this ingest does not serve; returns how many so far."""
        with self._lock:
            self._groups["refused"][module] += 1
            self._groups["counters"]["refused"] += 1
            self._dirty = True
            return self._groups["refused"][module]

    def __getitem__(self, name: str) -> int:
        return self.get(name)

    def get(self, name: str, group: str = "counters") -> int:
        with self._lock:
            return self._groups[group][name]

    def snapshot(self) -> dict[str, dict[str, int]]:
        with self._lock:
            return {g: dict(c) for g, c in self._groups.items()}

    # -- persistence -----------------------------------------------------
    def restore(self, saved: dict[str, int]) -> None:
        """Start from saved values (``group.name`` -> value)."""
        with self._lock:
            for key, value in saved.items():
                group, _, name = key.partition(".")
                if group in self._groups and name:
                    self._groups[group][name] += value

    def flat_with(self, more: dict[str, int]) -> dict[str, int]:
        """Every counter as ``group.name`` -> value, with ``more`` added to ``counters`` (not kept: for
        the transaction that stores what they count, `ingest.commit`)."""
        with self._lock:
            flat = {f"{g}.{k}": v for g, c in self._groups.items() for k, v in c.items()}
        for name, n in more.items():
            flat[f"counters.{name}"] = flat.get(f"counters.{name}", 0) + n
        return flat

    @staticmethod
    def flat(snapshot: dict[str, dict[str, int]]) -> dict[str, int]:
        """A `snapshot` as ``group.name`` -> value (what the store keeps)."""
        return {f"{g}.{k}": v for g, c in snapshot.items() for k, v in c.items()}

    def flat_if_changed(self) -> dict[str, int] | None:
        """Every counter as ``group.name`` -> value, or None if nothing changed since the last call."""
        with self._lock:
            if not self._dirty:
                return None
            self._dirty = False
            return {f"{g}.{k}": v for g, c in self._groups.items() for k, v in c.items()}
