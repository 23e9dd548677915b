"""What the store thread's workers share: the ingest's collaborators, never a stage.

`ingest.commit`, `ingest.results`, `ingest.gaps` and `ingest.housekeeping` run
in the store thread (`ingest.storeloop`) and share the store, the counters, the
alarms, the event bus (publish) and the answers to modules (acknowledge). The
stages themselves hand each other messages (`ingest.messages`); nothing here
refers back to a stage or to the service, so every import points down.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from camcal.core.ratelog import RateLimitedLog
from ingest.acknowledge import Acknowledge
from ingest.alarms import AlarmEvaluator
from ingest.config import IngestConfig
from ingest.counters import Counters
from ingest.events import EventBus
from ingest.links import Link
from storage.store import Store

log = logging.getLogger("camcal.ingest")


@dataclass
class StoreContext:
    """The store thread's collaborators and the ingest's state they read (see the module docstring)."""

    config: IngestConfig
    store: Store
    counters: Counters
    events: EventBus
    acknowledge: Acknowledge
    alarms: AlarmEvaluator
    dive_id: int
    run_id: int
    ingest_id: str
    #: The receiving thread's links (read here, written there).
    links: dict[str, Link]
    #: The analysis pool (`ingest.analysis_pool.AnalysisPool`): its crashes and backlog.
    analysis: Any
    #: Messages waiting in the checking and storing stages and in the analysis pool.
    backlog: Callable[[], int]
    credit: Any  # `ingest.fairness.Credit`: the window given to the modules
    #: The ingest's health (published once a second).
    health: Callable[[dict[str, dict[str, int]] | None], dict[str, Any]]
    latency_s: deque[float] = field(default_factory=lambda: deque(maxlen=2000))
    disk_free_gb: float | None = None
    warn: RateLimitedLog = field(default_factory=lambda: RateLimitedLog(log))

    def guarded(self, what: str, fn: Callable[..., Any], *args: Any) -> bool:
        """Run ``fn(*args)``; a failure is counted and logged, never raised. Returns whether it ran."""
        try:
            fn(*args)
            return True
        except Exception as exc:
            self.counters.inc("handler_errors")
            self.warn(
                logging.ERROR,
                f"{what}:{type(exc).__name__}",
                "ingest: %s failed: %s",
                what,
                exc,
                exc_info=True,
            )
            return False
