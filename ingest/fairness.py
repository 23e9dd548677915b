"""Turns between modules: each stage serves the modules round the table, a bounded amount each.

A `FairQueue` holds one first-in-first-out line per module. `take` hands
out a *turn*: at most ``per_module`` items of every module that has any,
modules in turn order, so a module with a thousand items waiting gets no
more of a turn than a module with one. Within a module the order is kept
(a resend is answered after the message it repeats). Bytes are counted per
module (``nbytes`` of each item) for the health and the admission
(`ingest.receive` refuses a module holding too much as ``busy``).
"""

from __future__ import annotations

import threading
from collections import OrderedDict, deque
from collections.abc import Callable
from typing import Any, Generic, TypeVar

T = TypeVar("T")


class FairQueue(Generic[T]):
    """Per-module lines served in turns; thread-safe (any thread puts, one takes)."""

    def __init__(self, size_of: Callable[[T], int] = lambda _: 0) -> None:
        self._lines: OrderedDict[str, deque[T]] = OrderedDict()
        self._bytes: dict[str, int] = {}
        self._size_of = size_of
        self._cond = threading.Condition()
        self._count = 0

    def put(self, module: str, item: T, *, front: bool = False) -> None:
        with self._cond:
            line = self._lines.get(module)
            if line is None:
                line = self._lines[module] = deque()
            if front:
                line.appendleft(item)
            else:
                line.append(item)
            self._bytes[module] = self._bytes.get(module, 0) + self._size_of(item)
            self._count += 1
            self._cond.notify_all()

    def take(
        self,
        per_module: int = 1,
        *,
        skip: set[str] | frozenset[str] = frozenset(),
        cost: Callable[[T], int] = lambda _: 1,
    ) -> list[T]:
        """One turn: items of each module that has some (but those in ``skip``), in turn order, up to
        ``per_module`` of their ``cost`` each (at least one item); the modules served move to the back."""
        out: list[T] = []
        with self._cond:
            for module in list(self._lines):
                if module in skip:
                    continue
                line = self._lines[module]
                spent = 0
                while line and (spent == 0 or spent + cost(line[0]) <= per_module):
                    item = line.popleft()
                    spent += cost(item)
                    self._bytes[module] -= self._size_of(item)
                    self._count -= 1
                    out.append(item)
                if line:
                    self._lines.move_to_end(module)
                else:
                    del self._lines[module]
        return out

    def wait(self, timeout: float) -> bool:
        """Wait until something is queued (or ``timeout``); whether anything is."""
        with self._cond:
            if not self._count:
                self._cond.wait(timeout)
            return self._count > 0

    def wake(self) -> None:
        """Wake a `wait` (something else, outside the queue, is to be done)."""
        with self._cond:
            self._cond.notify_all()

    def __len__(self) -> int:
        return self._count

    def bytes_of(self, module: str) -> int:
        with self._cond:
            return self._bytes.get(module, 0)

    def depths(self) -> dict[str, int]:
        """Items waiting per module (for the health)."""
        with self._cond:
            return {m: len(line) for m, line in self._lines.items()}


def sized(item: Any) -> int:
    """The ``nbytes`` of an item (what `FairQueue` counts)."""
    return int(getattr(item, "nbytes", 0))


class Credit:
    """The window (credit) given to the modules: ``base``, a quarter of it while the ship's queues
    are deep (`adapt`, once a second)."""

    def __init__(self, base: int) -> None:
        self.base = base
        self.value = base

    def adapt(self, backlog: int) -> None:
        self.value = self.base if backlog < 4 * self.base else max(1, self.base // 4)

    def __call__(self, module: str) -> int:
        return self.value
