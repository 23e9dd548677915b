"""The one event type: its wire form, its refusals, and its documentation in docs/protocol.md."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import get_type_hints

import pytest

from camcal.core.events import PAYLOADS, TRANSIENT_KINDS, Event, EventError, EventKind

PROTOCOL = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


def test_an_event_survives_the_wire_and_its_json_is_strict() -> None:
    e = Event(
        EventKind.RESULT, {"frame_id": 7, "i_center_gray": math.nan, "centroid_px": [1.5, math.inf]}, 1.7e9
    )
    e.module, e.dive_id, e.id = "A", 3, 42
    body = e.to_json()
    assert json.loads(body)["payload"] == {"frame_id": 7, "i_center_gray": None, "centroid_px": [1.5, None]}
    back = Event.from_json(body)
    assert (back.kind, back.id, back.module, back.dive_id, back.t) == (EventKind.RESULT, 42, "A", 3, 1.7e9)
    assert back.payload["frame_id"] == 7 and back.stored
    assert not Event(EventKind.HEALTH, {}, 0.0).stored


@pytest.mark.parametrize(
    "body",
    [b"not json", b"[1, 2]", b'{"kind": "nonsense"}', b'{"kind": "link", "payload": [1]}', b"\xff\xfe"],
)
def test_what_is_not_an_event_is_refused_with_a_reason(body: bytes) -> None:
    with pytest.raises(EventError):
        Event.from_json(body)


def test_docs_list_every_kind_with_every_payload_field() -> None:
    rows = {}
    for line in PROTOCOL.read_text(encoding="utf-8").splitlines():
        m = re.match(r"\| `(\w+)` \| (yes|no)[^|]*\| (.*) \|$", line)
        if m:
            rows[m.group(1)] = (m.group(2), m.group(3))
    assert set(rows) >= {k.value for k in EventKind}, "a kind missing from docs/protocol.md"
    for kind in EventKind:
        stored, text = rows[kind.value]
        assert (stored == "no") == (kind in TRANSIENT_KINDS), kind
        for field in get_type_hints(PAYLOADS[kind]) if kind in PAYLOADS else ():
            assert f"`{field}`" in text, f"{kind}: {field} is not documented"
