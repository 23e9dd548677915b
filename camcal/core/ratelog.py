"""A log that says a thing once, not a thousand times (the ingest's and the module's)."""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from typing import Any


class RateLimitedLog:
    """Logs the first occurrence of each key at once, then at most one line per ``interval_s``.

    The line after a quiet spell says how many similar ones were suppressed,
    so a flood of bad messages costs a few log lines, not a full disk.
    """

    def __init__(self, logger: logging.Logger, interval_s: float = 10.0) -> None:
        self.log = logger
        self.interval_s = interval_s
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()
        self._lock = threading.Lock()

    def __call__(self, level: int, key: str, msg: str, *args: Any, exc_info: bool = False) -> None:
        now = time.monotonic()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self.interval_s:
                self._suppressed[key] += 1
                return
            self._last[key] = now
            n = self._suppressed.pop(key, 0)
        if n:
            msg += f" ({n} similar suppressed in the last {self.interval_s:g} s)"
        self.log.log(level, msg, *args, exc_info=exc_info)
