"""A ``sensors`` payload checked in steps: a large batch costs the ship many short turns, not one long one.

`camcal.core.wire.codec.decode` checks a payload whole, row by row in Python:
100 000 rows of 64 columns (the largest a message may hold) take it ~15 s
of one core. A ship that serves several modules checks a payload with
`check_steps` instead: a generator that parses and checks at most
`STEP_BYTES` of rows per step with the C JSON parser and numpy, so that the
messages of the other modules are checked between the steps of a large one.

The rules are those of `dialect` and `sensors`, and the outcome is the
same: a payload up to `STEP_BYTES` goes through the exact path in one step;
a larger one is split at its rows (its layout checked first: a list of
``count`` lists, commas between them), and a part the fast path finds
anything odd in (a long number, an integer of 19 digits or more, a value
out of range, a row of another length) is checked again by the exact path,
which names the row and column. The rows come back as a `numpy` array of
every known column (`SENSOR_COLUMNS` order), NaN where a value is null or
the column absent (NaN cannot be sent: it is not JSON).
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Generator, Sequence
from typing import Any

import numpy as np

from camcal.core.wire import dialect
from camcal.core.wire.sensors import SENSOR_COLUMNS, SENSOR_SPEC, check_columns, check_rows

#: Bytes of rows parsed and checked per step (a few milliseconds of a core).
STEP_BYTES = 16 * 1024
#: Bytes scanned per step for the payload's layout (brackets, odd characters).
SCAN_BYTES = 4 * 1024 * 1024
#: The only bytes a sensor payload of numbers and nulls can hold (anything else: the exact path).
_ALLOWED = np.zeros(256, dtype=bool)
_ALLOWED[np.frombuffer(b"0123456789+-.eEnul[], \t\r\n", dtype=np.uint8)] = True
_OPEN, _CLOSE, _COMMA = ord("["), ord("]"), ord(",")
#: What the fast path leaves to the exact one: a number too long, or an integer that may not fit 64 bits.
_ODD = re.compile(rb"[-+0-9.eE]{%d,}|[0-9]{19,}" % (dialect.MAX_NUMBER_CHARS + 1))
_INDEX = {name: i for i, name in enumerate(SENSOR_COLUMNS)}


class PayloadError(ValueError):
    """A sensor payload that is refused, with what is wrong."""


def rows_array(samples: Sequence[dict[str, float | None]]) -> np.ndarray:
    """Checked rows (dicts of every known column, `check_rows`) as an array, NaN for null."""
    out = np.full((len(samples), len(SENSOR_COLUMNS)), np.nan)
    for r, s in enumerate(samples):
        for i, name in enumerate(SENSOR_COLUMNS):
            v = s.get(name)
            if v is not None:
                out[r, i] = v
    return out


def rows_dicts(rows: np.ndarray) -> list[dict[str, float | None]]:
    """An array of `rows_array` as dicts of every known column, None for null."""
    return [
        {name: (None if math.isnan(v) else v) for name, v in zip(SENSOR_COLUMNS, row, strict=True)}
        for row in rows.tolist()
    ]


def check_steps(
    columns: tuple[str, ...], payload: bytes | memoryview, count: int, step_bytes: int = STEP_BYTES
) -> Generator[None, None, np.ndarray]:
    """Check a payload of ``count`` rows in ``columns`` order, yielding between steps; returns its rows
    (`rows_array`). Raises `PayloadError` (a ValueError) naming what is wrong."""
    problem = check_columns(columns)
    if problem:
        raise PayloadError(problem)
    if len(payload) <= step_bytes:
        return _exact(columns, payload, count, 0)
    buf = np.frombuffer(payload, dtype=np.uint8)
    opens_l, closes_l, bad = [], [], None
    for at in range(0, len(buf), SCAN_BYTES):  # in blocks: no temporary as large as the payload
        block = buf[at : at + SCAN_BYTES]
        opens_l.append(np.flatnonzero(block == _OPEN) + at)
        closes_l.append(np.flatnonzero(block == _CLOSE) + at)
        odd = np.flatnonzero(~_ALLOWED[block])
        if bad is None and odd.size:
            bad = int(odd[0]) + at
        yield
    opens, closes = _layout(payload, np.concatenate(opens_l), np.concatenate(closes_l), count)
    yield
    if bad is not None:  # a character no number holds: the row it is in says what (or the layout does)
        r = int(np.searchsorted(opens, bad, side="right")) - 1
        if r >= 0 and bad <= closes[r]:
            _exact(columns, payload[opens[r] : closes[r] + 1], 1, r, wrap=True)
        raise PayloadError(f"not a list of {count} rows of numbers or null (byte {bad})")
    parts: list[np.ndarray] = []
    r = 0
    while r < count:
        end = int(np.searchsorted(opens, opens[r] + step_bytes, side="left"))
        end = min(max(end, r + 1), count)
        parts.append(_fast(columns, payload[opens[r] : closes[end - 1] + 1], r, end - r))
        r = end
        yield
    return np.concatenate(parts) if parts else np.empty((0, len(SENSOR_COLUMNS)))


def _blank(data: bytes | memoryview) -> bool:
    return not bytes(data).strip(b" \t\r\n")


def _layout(
    payload: bytes | memoryview, opens: np.ndarray, closes: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Where each row starts and ends, after checking the payload is ``[row, row, ...]`` of ``count``
    rows, nothing nested in a row, commas between them and only blanks around."""
    where = PayloadError(f"payload must be a list of {count} rows, each a list of numbers or null")
    if len(opens) != count + 1 or len(closes) != count + 1:
        raise where
    first, last = int(opens[0]), int(closes[-1])
    opens, closes = opens[1:], closes[:-1]
    if not (_blank(payload[:first]) and _blank(payload[last + 1 :])):
        raise where
    if count == 0:
        if not _blank(payload[first + 1 : last]):
            raise where
        return opens, closes
    # Rows open and close in turn, inside the outer list: no row nests another, none is left open.
    if not (first < opens[0] and closes[-1] < last and (opens < closes).all()):
        raise where
    if not ((closes[:-1] < opens[1:]).all() and _blank(payload[first + 1 : int(opens[0])])):
        raise where
    if not _blank(payload[int(closes[-1]) + 1 : last]):
        raise where
    # Between two rows one comma, and blanks: "],[" almost always; anything longer is read alone.
    buf = np.frombuffer(payload, dtype=np.uint8)
    gap = opens[1:] - closes[:-1] - 1
    tight = gap == 1
    if (buf[closes[:-1][tight] + 1] != _COMMA).any():
        raise where
    for c, o in zip(closes[:-1][~tight].tolist(), opens[1:][~tight].tolist(), strict=True):
        if bytes(payload[c + 1 : o]).strip(b" \t\r\n") != b",":
            raise where
    return opens, closes


def _fast(columns: tuple[str, ...], part: bytes | memoryview, first_row: int, n: int) -> np.ndarray:
    """Rows ``first_row`` .. of a part (``[...],[...]``): parsed by the C parser, checked by numpy; anything
    odd goes to the exact path, which names it."""
    text = b"[" + bytes(part) + b"]"
    if _ODD.search(text) is None:
        try:
            values = np.array(json.loads(text), dtype=np.float64)
        except (ValueError, TypeError):
            values = None
        if values is not None and values.shape == (n, len(columns)) and not np.isinf(values).any():
            out = np.full((n, len(SENSOR_COLUMNS)), np.nan)
            ok = True
            for i, name in enumerate(columns):
                k = _INDEX.get(name)
                if k is None:
                    continue
                col, spec = values[:, i], SENSOR_SPEC[k]
                missing = np.isnan(col)
                present = col[~missing]
                if (name == "t_unix_s" and missing.any()) or (
                    (present < spec.lo).any() or (present > spec.hi).any()
                ):
                    ok = False
                    break
                out[:, k] = col
            if ok:
                return out
    return _exact(columns, text, n, first_row)


def _exact(
    columns: tuple[str, ...], data: Any, count: int, first_row: int, *, wrap: bool = False
) -> np.ndarray:
    """The exact path (`dialect.loads`, `check_rows`) on rows ``first_row`` ..; raises `PayloadError`."""
    text = b"[" + bytes(data) + b"]" if wrap else data
    try:
        rows = dialect.loads(text, max_depth=2)
        return rows_array(check_rows(columns, rows, count, first_row=first_row))
    except ValueError as exc:
        raise PayloadError(str(exc)) from None
