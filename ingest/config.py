"""The settings of one ingest process (`IngestConfig`)."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from camcal.core import wire
from camcal.core.frameset import Setup
from ingest.alarms import AlarmLimits


@dataclass(frozen=True)
class IngestConfig:
    """Settings of one ingest process."""

    data_dir: Path
    bind: str = "tcp://*:5555"
    events_bind: str | None = "tcp://127.0.0.1:5556"
    events_curve: bool | None = None  # CURVE on the events port: None beyond loopback (`eventport`)
    db_url: str | None = None
    window: int = 8
    heartbeat_s: float = 1.0
    link_timeout_s: float = 5.0
    ack_batch_s: float = 0.02
    workers: int = 0
    max_payload_bytes: int = wire.MAX_PAYLOAD_BYTES
    fsync: bool = True
    sqlite_synchronous: str = "FULL"
    dive_name: str | None = None
    setup: Setup = field(default_factory=Setup)
    visit_idle_close_s: float = 60.0  # no frame result for this long: the open λ_att visits are final
    command_retry_s: float = 3.0
    retention_days: float | None = None
    calibration: str | None = None
    thumbnails: bool = True
    alarm_limits: AlarmLimits = field(default_factory=AlarmLimits)
    modules: tuple[str, ...] = ()  # the modules this process serves; empty: any module
    keys_dir: Path | None = None  # the link's CURVE keys (`camcal.core.wire.keys`)
    plaintext: bool = False  # no keys, no encryption: a lab bench only, and only when asked for
    #: Bytes of one module's data the ship holds before it is stored; more is refused ``busy``.
    module_queue_bytes: int = 2 * wire.MAX_PAYLOAD_BYTES

    @property
    def n_workers(self) -> int:
        return self.workers or os.cpu_count() or 1

    def serves(self, module: str) -> bool:
        return not self.modules or module in self.modules
