"""The protocol as a JSON Schema, generated from the models (``docs/protocol-v1.schema.json``).

Regenerate the published file with ``python -m camcal.core.wire.schema >
docs/protocol-v1.schema.json``; a test fails when it is out of date. The
schema describes headers; the payloads (an image, or rows of sensor values)
and the dialect's limits are described in its ``description`` and in
``docs/protocol.md``.
"""

from __future__ import annotations

import json
from typing import Any

from camcal.core.wire.codec import ADAPTER
from camcal.core.wire.dialect import MAX_HEADER_DEPTH, MAX_NUMBER_CHARS
from camcal.core.wire.limits import MAX_HEADER_BYTES
from camcal.core.wire.reasons import REASONS
from camcal.core.wire.sensors import SENSOR_SPEC

#: Version of the schema document: the protocol version, then a revision for additions that keep it.
SCHEMA_VERSION = "1.10"


def protocol_schema() -> dict[str, Any]:
    """The JSON Schema of every message header of protocol version 1."""
    schema = ADAPTER.json_schema(mode="validation", ref_template="#/$defs/{model}")
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["$id"] = f"https://camcal.example/protocol/{SCHEMA_VERSION}/schema.json"
    schema["title"] = f"camcal module protocol {SCHEMA_VERSION}: message headers"
    schema["description"] = (
        f"Headers are UTF-8 JSON objects of at most {MAX_HEADER_BYTES} bytes, nested at most "
        f"{MAX_HEADER_DEPTH} deep; numbers are finite, at most {MAX_NUMBER_CHARS} characters, integers "
        "signed 64-bit; no NaN or Infinity; no key twice in one object. Unknown fields are ignored. "
        "See docs/protocol.md."
    )
    schema["x-camcal-version"] = SCHEMA_VERSION
    schema["x-nack-reasons"] = {
        r.name: {"retry": r.retry, "until_it_works": r.until_it_works, "meaning": r.meaning}
        for r in REASONS.values()
    }
    schema["x-sensor-columns"] = [
        {"name": c.name, "unit": c.unit, "min": c.lo, "max": c.hi, "meaning": c.meaning} for c in SENSOR_SPEC
    ]
    return schema


def schema_text() -> str:
    return json.dumps(protocol_schema(), indent=2, ensure_ascii=False, sort_keys=True) + "\n"


if __name__ == "__main__":  # pragma: no cover - a maintainer's command
    print(schema_text(), end="")  # noqa: T201
