"""Time bounds a test may assert, from what the machine is doing while it runs.

A bound on seconds is behaviour only where the product promises one (a daemon ends soon after
SIGTERM, a port in use stops `camcal up` at once): its figure is for an idle machine. A ship's
computer, like the one these tests share, is often busy: then every process waits its turn for a
core. `Pace` samples how many processes want a core per core (the load average and the processes
runnable right now, from /proc/loadavg) before and after what is timed, and stretches a bound by
that factor: the same promise on a busy machine, never a looser one on an idle machine.
"""

from __future__ import annotations

from camcal.core.procinfo import busy_factor


class Pace:
    """Samples `busy_factor` over an operation; `bound` stretches an idle machine's bound by the
    busiest sample (taken once more when asked, so a load that rose meanwhile counts)."""

    def __init__(self) -> None:
        self.samples = [busy_factor()]

    def sample(self) -> float:
        self.samples.append(busy_factor())
        return self.samples[-1]

    @property
    def factor(self) -> float:
        return max(self.samples)

    def bound(self, idle_s: float) -> float:
        self.sample()
        return idle_s * self.factor

    def __str__(self) -> str:
        return f"machine busy ×{self.factor:.1f} (processes wanting each core)"
