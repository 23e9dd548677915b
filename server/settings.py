"""What the server needs to run."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from camcal.core.schedule import CameraLimits
from storage.queries.divestate import DiveRules


@dataclass(frozen=True)
class ServerSettings:
    """Settings of one server process.

    ``events`` is the ingest's event publisher (``camcal ingest --events``);
    None runs the server on the database alone (review of past dives). An
    events port beyond loopback speaks CURVE (``events_curve``: see
    `camcal.core.eventport`), with the ship's key pair from ``keys_dir``.
    ``operator_tokens`` maps operator names to tokens; without any, nobody
    can change anything (watching needs no token). ``station_depth_m``, the
    dive plan's station depth, tells the live view's station from test stops.
    ``simulation_speed``: the modules are `camcal up`'s simulated ones, at that
    speed; their clock is mapped onto the ship's (`camcal.core.clockmap`), and
    the pages say so (None: real modules).

    The bounds (`server.guard`, `server.jobs`, the live WebSocket): request
    bodies up to ``max_body_bytes`` (a route may allow more), at most
    ``max_requests_per_client`` requests and ``max_websockets_per_client``
    live connections of one address at once, ``exports_at_once`` exports
    and one re-analysis at a time (``max_reanalyses_queued`` waiting),
    ``previews_at_once`` schedule previews for browsers without a token and
    ``operator_previews_at_once`` more for operators,
    ``token_failures`` wrong tokens of one address within ``token_window_s``.
    ``trusted_proxies``: addresses or networks of reverse proxies whose
    ``X-Forwarded-For`` names the client (`server.guard.TrustedProxies`); none by default.
    """

    data_dir: Path = Path("camcal-data")
    db_url: str | None = None
    events: str | None = "tcp://127.0.0.1:5556"
    keys_dir: Path | None = None
    events_curve: bool | None = None
    operator_tokens: dict[str, str] = field(default_factory=dict)
    stale_after_s: float = 5.0
    client_queue: int = 256
    reanalysis_workers: int = 1
    run_migrations: bool = True
    camera_limits: CameraLimits = field(default_factory=CameraLimits)
    linear_range: tuple[float, float] = (5.0, 240.0)
    readout_s: float = 0.8
    lem_dwell_s: float | None = 60.0
    station_depth_m: float | None = None
    max_body_bytes: int = 1 << 20
    max_requests_per_client: int = 32
    max_websockets_per_client: int = 16
    max_ws_message_bytes: int = 4096
    exports_at_once: int = 1
    previews_at_once: int = 2
    operator_previews_at_once: int = 2
    max_reanalyses_queued: int = 4
    token_failures: int = 10
    token_window_s: float = 60.0
    simulation_speed: float | None = None
    trusted_proxies: tuple[str, ...] = ()
    #: When a dive has ended (`storage.queries.divestate`): the pages show it open or ended, and why.
    dive_rules: DiveRules = field(default_factory=DiveRules)
