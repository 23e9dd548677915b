"""What the ship knows of each module's connection: the receiving thread writes it, others read it."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

#: Heartbeats the module's clock offset is estimated over (`Link.clock_offset_s`), and how many
#: it needs before it says anything.
CLOCK_BEATS = 30
CLOCK_MIN_BEATS = 5


@dataclass
class Link:
    """What the ship knows of one module's connection."""

    module: str
    identity: bytes
    boot: str = ""
    up: bool = False
    down_reason: str = ""  # "bye" (signed off) or "timeout" while down
    last_seen_mono: float = 0.0
    last_seen_unix_s: float = 0.0
    welcomed: bool = False
    schedule: dict[str, Any] = field(default_factory=dict)
    outbox_pending: int = 0
    in_flight: int = 0
    last_seq: int = 0  # the highest sequence number of ``boot`` the module says it has produced
    card_skipped: int = 0  # messages the module could not keep on its SD card (not taken) this boot
    card_error: str | None = None
    capture_errors: int = 0  # camera captures that failed this boot (the module retries them)
    camera_error: str | None = None
    sensor_errors: int = 0  # sensor reads that failed this boot
    sensor_error: str | None = None
    deferred_shots: int = 0  # shots its runner took at a later turn of their colour this boot
    waiting: dict[str, Any] | None = None  # why it takes no picture now (`camcal.core.wire.Waiting`)
    frames: deque[float] = field(default_factory=lambda: deque(maxlen=2000))
    last_frame_unix_s: float | None = None
    last_heartbeat_sent: float = 0.0
    clock_offset_s: float | None = None
    clock_readings: deque[float] = field(default_factory=lambda: deque(maxlen=CLOCK_BEATS))
    #: Data messages taken in and not answered yet, (boot, seq) -> payload bytes: the module's
    #: window as the ship sees it, and what it holds of the module.
    unanswered: dict[tuple[str, int], int] = field(default_factory=dict)
    unanswered_bytes: int = 0
    busy_refused: int = 0  # data messages refused as ``busy`` (the module held too much on the ship)

    def settle(self, boot: str, seq: int) -> None:
        """A data message of the module was answered."""
        self.unanswered_bytes -= self.unanswered.pop((boot, seq), 0)
