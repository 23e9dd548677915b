"""The protocol's JSON dialect: standard JSON (RFC 8259) with limits, checked before any model.

Headers and sensor payloads are parsed here and nowhere else. What the
dialect refuses, whatever the message type:

* text that is not UTF-8, or not JSON;
* ``NaN``, ``Infinity`` and ``-Infinity`` (not JSON, though Python writes them);
* a number written with more than `MAX_NUMBER_CHARS` characters;
* an integer outside the signed 64-bit range;
* a number that is not a finite double (``1e400``);
* the same key twice in one object;
* nesting deeper than the caller's limit (headers: `MAX_HEADER_DEPTH`).

Every refusal is a `DialectError` (a `ValueError`) that says what is wrong;
nothing else escapes `loads`, whatever the bytes.
"""

from __future__ import annotations

import json
import math
from typing import Any

#: Longest number literal accepted (sign, digits, point and exponent included).
MAX_NUMBER_CHARS = 40
#: Integers are signed 64-bit: what every database column of the ship holds.
INT_MIN, INT_MAX = -(2**63), 2**63 - 1
#: Deepest nesting of a header (version 1 needs 3: a command's schedule holds lists; room to grow).
MAX_HEADER_DEPTH = 8


class DialectError(ValueError):
    """Bytes that are not JSON of the protocol's dialect."""


def _int(text: str) -> int:
    if len(text) > MAX_NUMBER_CHARS:
        raise DialectError(f"number of {len(text)} characters (at most {MAX_NUMBER_CHARS})")
    value = int(text)
    if not INT_MIN <= value <= INT_MAX:
        raise DialectError(f"integer {text} outside the signed 64-bit range")
    return value


def _float(text: str) -> float:
    if len(text) > MAX_NUMBER_CHARS:
        raise DialectError(f"number of {len(text)} characters (at most {MAX_NUMBER_CHARS})")
    value = float(text)
    if not math.isfinite(value):
        raise DialectError(f"number {text} is not a finite double")
    return value


def _constant(name: str) -> Any:
    raise DialectError(f"{name} is not JSON (numbers must be finite)")


def _object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise DialectError(f"key {key[:40]!r} appears twice in one object")
        out[key] = value
    return out


def depth(value: Any) -> int:
    """Nesting depth of a parsed value: 0 for a scalar, 1 for a flat list or object, ...

    Iterative, so that no value, however deep, can exhaust the stack.
    """
    deepest = 0
    stack: list[tuple[Any, int]] = [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, dict):
            v = v.values()
        elif not isinstance(v, list):
            deepest = max(deepest, d)
            continue
        deepest = max(deepest, d + 1)
        stack.extend((child, d + 1) for child in v)
    return deepest


def loads(data: bytes | bytearray | memoryview, *, max_depth: int) -> Any:
    """Parse ``data`` as JSON of the dialect; raise `DialectError` naming what is wrong."""
    try:
        text = bytes(data).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise DialectError(f"not UTF-8 ({exc.reason} at byte {exc.start})") from None
    try:
        value = json.loads(
            text,
            parse_int=_int,
            parse_float=_float,
            parse_constant=_constant,
            object_pairs_hook=_object,
        )
    except DialectError:
        raise
    except RecursionError:
        raise DialectError(f"nested deeper than {max_depth}") from None
    except ValueError as exc:  # json.JSONDecodeError and int() of odd literals
        raise DialectError(f"not JSON: {exc}") from None
    if depth(value) > max_depth:
        raise DialectError(f"nested deeper than {max_depth}")
    return value


def dumps(value: Any) -> bytes:
    """Compact JSON of the dialect (refuses NaN and infinities rather than writing them)."""
    return json.dumps(value, separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode()
