"""What the ship knows of each module's connection: the receiving thread writes it, others read it."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

from camcal.core.clockmap import ModuleClock

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
    #: Its clock as its hello described it (a simulated one's rate and anchor; `camcal.core.clockmap`).
    clock: ModuleClock = field(default_factory=ModuleClock)
    #: The boot that ``clock`` and ``clock_readings`` are of.
    clock_boot: str = ""
    #: Data messages taken in and not answered yet, (boot, seq) -> payload bytes: the module's
    #: window as the ship sees it, and what it holds of the module.
    unanswered: dict[tuple[str, int], int] = field(default_factory=dict)
    unanswered_bytes: int = 0
    busy_refused: int = 0  # data messages refused as ``busy`` (the module held too much on the ship)

    def clock_map(self) -> ModuleClock:
        """Its clock mapped onto the ship's with the offset measured so far (from its first reading:
        before five beats the estimate is rough, and `clock_offset_s` stays None)."""
        return self.clock.with_offset(max(self.clock_readings)) if self.clock_readings else self.clock

    def clock_reading(self, boot: str, sent_unix_s: float, arrived_unix_s: float) -> None:
        """One message's offset reading (a hello's or a heartbeat's); a new boot starts afresh."""
        if boot != self.clock_boot:
            self.clock_boot = boot
            self.clock_readings.clear()
            self.clock_offset_s = None
        self.clock_readings.append(self.clock.reading(sent_unix_s, arrived_unix_s))
        if len(self.clock_readings) >= CLOCK_MIN_BEATS:  # (before: not known yet)
            self.clock_offset_s = max(self.clock_readings)

    def settle(self, boot: str, seq: int) -> None:
        """A data message of the module was answered."""
        self.unanswered_bytes -= self.unanswered.pop((boot, seq), 0)
