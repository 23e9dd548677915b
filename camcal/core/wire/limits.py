"""The protocol's fixed limits: sizes, counts and the window timestamps must fall in."""

from __future__ import annotations

from datetime import UTC, datetime

from camcal.core.wire.dialect import INT_MAX, INT_MIN

#: Largest header accepted (bytes of JSON).
MAX_HEADER_BYTES = 64 * 1024
#: Largest payload accepted by default (`IngestConfig.max_payload_bytes`).
MAX_PAYLOAD_BYTES = 32 * 1024 * 1024
#: Most sensor rows in one ``sensors`` message.
MAX_SENSOR_ROWS = 100_000
#: Timestamps must fall in this window (UTC): catches clocks never set and garbage alike.
TIME_MIN = datetime(2000, 1, 1, tzinfo=UTC)
TIME_MAX = datetime(2100, 1, 1, tzinfo=UTC)
TIME_MIN_UNIX_S = TIME_MIN.timestamp()
TIME_MAX_UNIX_S = TIME_MAX.timestamp()
#: A message's ``sent_at`` may read from 1970 on: a module whose clock was never set (a Raspberry
#: Pi's clock without its battery starts at 1970) must still link, so that the ship can say so.
SENT_AT_MIN = datetime(1970, 1, 1, tzinfo=UTC)

__all__ = [
    "INT_MAX",
    "INT_MIN",
    "MAX_HEADER_BYTES",
    "MAX_PAYLOAD_BYTES",
    "MAX_SENSOR_ROWS",
    "SENT_AT_MIN",
    "TIME_MAX",
    "TIME_MAX_UNIX_S",
    "TIME_MIN",
    "TIME_MIN_UNIX_S",
]
