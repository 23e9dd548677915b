"""Hypothesis strategies from the published JSON Schema of the protocol (the subset it uses).

Generates headers a stranger's module could send if it followed the schema
and nothing else: every keyword the schema uses is honoured (types, const,
enum, patterns, lengths, bounds, formats, tuples, references). The schema
knows nothing of the time window or of payloads, so some of what it allows
the ship still refuses: that is what the fuzzer is for.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from hypothesis import strategies as st

INT64 = 2**63 - 1


def strategy(schema: dict[str, Any], defs: dict[str, Any]) -> st.SearchStrategy[Any]:
    """A strategy for values valid against ``schema`` (``$ref`` resolved in ``defs``)."""
    if "$ref" in schema:
        return strategy(defs[schema["$ref"].rsplit("/", 1)[1]], defs)
    if "const" in schema:
        return st.just(schema["const"])
    if "enum" in schema:
        return st.sampled_from(schema["enum"])
    if "anyOf" in schema:
        return st.one_of([strategy(s, defs) for s in schema["anyOf"]])
    if "oneOf" in schema:
        return st.one_of([strategy(s, defs) for s in schema["oneOf"]])
    kind = schema.get("type")
    if kind == "object":
        return _object(schema, defs)
    if kind == "array":
        return _array(schema, defs)
    if kind == "string":
        return _string(schema)
    if kind == "integer":
        lo, hi = schema.get("minimum", -INT64 - 1), schema.get("maximum", INT64)
        if "exclusiveMinimum" in schema:
            lo = schema["exclusiveMinimum"] + 1
        return st.integers(lo, hi) | st.sampled_from(sorted({lo, hi}))  # bounds are where bugs live
    if kind == "number":
        lo = schema.get("minimum", schema.get("exclusiveMinimum"))
        hi = schema.get("maximum", schema.get("exclusiveMaximum"))
        return st.floats(
            lo,
            hi,
            exclude_min="exclusiveMinimum" in schema,
            exclude_max="exclusiveMaximum" in schema,
            allow_nan=False,
            allow_infinity=False,
        )
    if kind == "boolean":
        return st.booleans()
    if kind == "null":
        return st.none()
    raise NotImplementedError(f"schema keyword set not handled: {sorted(schema)}")


def _object(schema: dict[str, Any], defs: dict[str, Any]) -> st.SearchStrategy[dict[str, Any]]:
    props = schema.get("properties", {})
    required = set(schema.get("required", []))
    return st.fixed_dictionaries(
        {k: strategy(v, defs) for k, v in props.items() if k in required},
        optional={k: strategy(v, defs) for k, v in props.items() if k not in required},
    )


def _array(schema: dict[str, Any], defs: dict[str, Any]) -> st.SearchStrategy[list[Any]]:
    if "prefixItems" in schema:
        return st.tuples(*(strategy(s, defs) for s in schema["prefixItems"])).map(list)
    items = strategy(schema.get("items", {"type": "null"}), defs)
    return st.lists(items, min_size=schema.get("minItems", 0), max_size=min(schema.get("maxItems", 5), 5))


def _string(schema: dict[str, Any]) -> st.SearchStrategy[str]:
    lo, hi = schema.get("minLength", 0), schema.get("maxLength", 80)
    if schema.get("format") == "date-time":
        return st.datetimes(datetime(1, 1, 1), datetime(9999, 12, 31), timezones=st.just(UTC)).map(
            lambda d: d.isoformat().replace("+00:00", "Z")
        )
    if "pattern" in schema:
        return st.from_regex(schema["pattern"], fullmatch=True).filter(lambda s: lo <= len(s) <= hi)
    return st.text(min_size=lo, max_size=min(hi, 80))
