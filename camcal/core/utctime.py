"""Times written by people and other tools: ISO 8601, read as UTC when they name no zone.

A frame set's ``timestamp`` column, a command's ``--from``: ``2021-09-05T03:12:44Z``,
``2021-09-05T03:12:44.5+00:00``, ``2021-09-05 03:12:44`` and ``2021-09-05`` all
read. A time without a zone is UTC (the frame-set format says so), never the
local time of the machine that reads it: a ship's laptop set to its port's
zone would otherwise move every frame by hours.
"""

from __future__ import annotations

from datetime import UTC, datetime

#: What an unreadable time is told to look like.
EXAMPLE = "2021-09-05T03:12:44Z"


def parse_utc(text: str) -> datetime:
    """An aware datetime; ValueError naming the text and an example if it is not ISO 8601."""
    value = text.strip()
    try:
        t = datetime.fromisoformat(value[:-1] + "+00:00" if value[-1:] in ("Z", "z") else value)
    except ValueError:
        raise ValueError(f"{text!r} is not an ISO 8601 time such as {EXAMPLE}") from None
    return t if t.tzinfo is not None else t.replace(tzinfo=UTC)


def parse_utc_unix_s(text: str) -> float:
    """`parse_utc` as UNIX seconds."""
    return parse_utc(text).timestamp()


def iso_utc(unix_s: float | None) -> str | None:
    """UNIX seconds as ISO 8601 UTC to the millisecond, ``2021-09-05T03:12:44.500Z`` (None, NaN and a time no
    calendar holds, as a corrupt row may, give None):
    what an export writes beside each ``*_unix_s`` time, for people and spreadsheets."""
    if unix_s is None or unix_s != unix_s:  # None or NaN
        return None
    try:
        t = datetime.fromtimestamp(float(unix_s), UTC)
    except (OverflowError, OSError, ValueError):  # beyond what a calendar date can say (a corrupt row)
        return None
    return t.isoformat(timespec="milliseconds").replace("+00:00", "Z")
