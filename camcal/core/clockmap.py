"""One clock per dive: a module's clock mapped onto the ship's.

A module stamps its frames and samples with its own clock; the ship stamps
what it receives, its alarms, commands and audit entries with its own. A
real module's clock runs at the ship's rate, off by an offset that may drift;
a simulated one (``camcal up``) runs ``rate`` times as fast (10×), and says
at the handshake how: its rate and what it reads (``module_at``) at a real
time (``real_at``). At every heartbeat the ship measures the offset: what
the module's clock reads against what that predicts at the moment the beat
arrived. A beat queued behind frames arrives late and reads as a clock
behind, never ahead, so the largest of the recent readings is the estimate
(NTP's minimum-delay filter).

With rate 1 and no anchor this is the classic offset, module minus ship:
``ship(t) = t - offset``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class ModuleClock:
    """How a module's clock maps onto the ship's (see the module docstring).

    ``offset_s`` is in seconds of the module's clock: what it read minus what the anchor predicts.
    """

    rate: float = 1.0
    module_at_unix_s: float = 0.0
    real_at_unix_s: float = 0.0
    offset_s: float = 0.0

    def reading(self, sent_unix_s: float, arrived_unix_s: float) -> float:
        """The offset one message says: its ``sent_at`` (module clock) against its arrival (ship)."""
        return sent_unix_s - self.module_at_unix_s - self.rate * (arrived_unix_s - self.real_at_unix_s)

    def ship(self, t_unix_s: float) -> float:
        """A time of the module's clock on the ship's clock."""
        return self.real_at_unix_s + (t_unix_s - self.module_at_unix_s - self.offset_s) / self.rate

    def module(self, t_ship_unix_s: float) -> float:
        """A time of the ship's clock on the module's (the inverse of `ship`)."""
        return self.module_at_unix_s + self.offset_s + self.rate * (t_ship_unix_s - self.real_at_unix_s)

    def with_offset(self, offset_s: float) -> ModuleClock:
        return replace(self, offset_s=offset_s)

    @property
    def simulated(self) -> bool:
        return self.rate != 1.0


def handshake_clock(rate: float | None, reads_unix_s: float | None, at_unix_s: float | None) -> ModuleClock:
    """The anchor a ``hello`` gives: none for a clock at the ship's rate (the offset is then module
    minus ship), else the simulated clock's rate and reading at a real time."""
    if rate is None or reads_unix_s is None or at_unix_s is None:
        return ModuleClock()
    return ModuleClock(rate, reads_unix_s, at_unix_s)
