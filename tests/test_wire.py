"""The wire protocol: round trips, every kind of malformed message, the dialect, the schema, fuzzing."""

from __future__ import annotations

import contextlib
import json
from datetime import UTC, datetime
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camcal.core import wire
from camcal.core.wire import dialect
from camcal.core.wire.schema import schema_text
from tests.utils.wiremsgs import frame_parts, png_bytes, sensors_parts

REPO = Path(__file__).resolve().parents[1]


def test_round_trip_of_every_message_type() -> None:
    rows = wire.sensors_payload([[1.7e9, 4.0, 30.0, 0.0, 0.0, 9.81, 0.1, 0.0, 0.0, 3400.0]])
    msgs = [
        (wire.Hello(module="A", boot="b1"), None),
        (wire.ModuleHeartbeat(module="A", boot="b1", outbox_pending=3), None),
        (
            wire.SensorsMsg(
                module="A", boot="b1", seq=2, count=1, size=len(rows), sha256=wire.sha256_hex(rows)
            ),
            rows,
        ),
        (wire.CommandStatus(module="A", boot="b1", command_id="c1", state="done"), None),
        (wire.Welcome(module="ship", window=8), None),
        (wire.Ack(module="ship", ranges=(("b1", 1, 5),), window=4), None),
        (wire.Nack(module="ship", boot="b1", seq=3, reason="bad_payload", retry=True), None),
        (wire.Nack(module="ship", reason="bad_header", detail="not JSON"), None),
        (wire.ShipHeartbeat(module="ship", window=8), None),
        (wire.Command(module="ship", command_id="c1", action="pause"), None),
        (wire.Bye(module="A", boot="b1"), None),
    ]
    for msg, pl in msgs:
        frames = [bytes(f) for f in wire.encode(msg, pl)]
        out, out_pl = wire.decode(frames)
        assert out == msg
        if msg.type == "sensors":
            assert out_pl[0]["t_unix_s"] == 1.7e9 and out_pl[0]["depth_m"] == 3400.0
        else:
            assert out_pl is None
    frame, pl = wire.decode(frame_parts())
    assert frame.seq == 7 and frame.wavelength_nm == 460 and bytes(pl) == png_bytes()


BIG = 2**63
DEEP = b"[" * 5000 + b"]" * 5000
CASES = [
    # (what, frames, reason) -- each case of the protocol issue, and their neighbours
    ("gain NaN", frame_parts(raw={"gain_db": "NaN"}), "bad_header"),
    ("gain Infinity", frame_parts(raw={"gain_db": "Infinity"}), "bad_header"),
    ("gain -Infinity", frame_parts(raw={"gain_db": "-Infinity"}), "bad_header"),
    ("gain 1e400", frame_parts(raw={"gain_db": "1e400"}), "bad_header"),
    ("gain 1e308", frame_parts(gain_db=1e308), "invalid_field"),
    ("gain a string", frame_parts(gain_db="6"), "invalid_field"),
    ("gain true", frame_parts(gain_db=True), "invalid_field"),
    ("exposure 0", frame_parts(exposure_s=0), "invalid_field"),
    ("depth inf-ish", frame_parts(depth_m=1e300), "invalid_field"),
    ("seq 2^63", frame_parts(raw={"seq": str(BIG)}), "bad_header"),
    ("seq 0", frame_parts(seq=0), "invalid_field"),
    ("seq 2.0", frame_parts(seq=2.0), "invalid_field"),
    ("schedule_version 2^63", frame_parts(raw={"schedule_version": str(BIG)}), "bad_header"),
    ("schedule_version 2^40", frame_parts(schedule_version=2**40), "invalid_field"),
    ("wavelength 2^63", frame_parts(raw={"wavelength_nm": str(BIG)}), "bad_header"),
    ("wavelength 5", frame_parts(wavelength_nm=5), "invalid_field"),
    ("5000-digit number", frame_parts(raw={"seq": "9" * 5000}), "bad_header"),
    ("year 0001", frame_parts(captured_at="0001-01-01T00:00:00Z"), "invalid_field"),
    ("year 9999", frame_parts(captured_at="9999-12-31T23:59:59Z"), "invalid_field"),
    ("time as a number", frame_parts(captured_at=1.7e9), "invalid_field"),
    (
        "sent_at 1969",
        frame_parts(sent_at="1969-12-31T23:59:59Z"),
        "invalid_field",
    ),  # (1970 on: a clock never set)
    ("captured_at 1970", frame_parts(captured_at="1970-01-01T00:05:00Z"), "invalid_field"),
    ("boot ..", frame_parts(boot=".."), "invalid_field"),
    ("boot .", frame_parts(boot="."), "invalid_field"),
    ("module ...", frame_parts(module="..."), "invalid_field"),
    ("boot with a slash", frame_parts(boot="a/b"), "invalid_field"),
    ("camera of 1000 characters", frame_parts(camera="A" * 1000), "invalid_field"),
    ("file escaping", frame_parts(file="../../etc/passwd"), "invalid_field"),
    ("width mismatch", frame_parts(width_px=65), "bad_image"),
    ("16-bit PNG", frame_parts(image=np.zeros((48, 64), np.uint16)), "bad_image"),
    ("colour PNG", frame_parts(image=np.zeros((48, 64, 3), np.uint8)), "bad_image"),
    ("not a PNG", frame_parts(payload=b"GIF89a" + bytes(40)), "bad_image"),
    ("wrong sha256", frame_parts(sha256="0" * 64), "bad_payload"),
    ("wrong size", frame_parts(size=3), "bad_payload"),
    ("duplicate key", [b'{"v":1,"v":1,"type":"hello","module":"A","boot":"b"}'], "bad_header"),
    ("nested 30000 deep", [b'{"v":1,"x":' + b"[" * 30000 + b"]" * 30000 + b"}"], "bad_header"),
    ("nested 9 deep", [b'{"v":1,"x":' + b"[" * 8 + b"]" * 8 + b"}"], "bad_header"),
    ("not UTF-8", [b'{"v":1,"type":"\xff"}'], "bad_header"),
    ("a JSON list", [b"[1,2]"], "bad_header"),
    ("version true", [b'{"v":true,"type":"hello","module":"A","boot":"b"}'], "bad_version"),
    ("version 2", [b'{"v":2,"type":"hello","module":"A","boot":"b"}'], "bad_version"),
    ("unknown type", [b'{"v":1,"type":"hack","module":"A"}'], "unknown_type"),
    ("three frames", [b"{}", b"", b""], "bad_framing"),
    ("hello with payload", [b'{"v":1,"type":"hello","module":"A","boot":"b"}', b"x"], "bad_framing"),
    ("frame without payload", frame_parts()[:1], "bad_framing"),
    ("sensor t null", sensors_parts([[None, 4.0]], ("t_unix_s", "temperature_c")), "invalid_field"),
    ("sensor NaN", sensors_parts(b"[[NaN,4.0]]", ("t_unix_s", "temperature_c")), "invalid_field"),
    ("sensor t missing", sensors_parts([[4.0]], ("temperature_c",)), "invalid_field"),
    ("sensor columns twice", sensors_parts([[1.7e9, 1.7e9]], ("t_unix_s", "t_unix_s")), "invalid_field"),
    ("sensor humidity 1e308", sensors_parts([[1.7e9, 1e308]], ("t_unix_s", "humidity_pct")), "invalid_field"),
    ("sensor t year 9999", sensors_parts([[2.5e11]], ("t_unix_s",)), "invalid_field"),
    (
        "sensor deep nesting",
        sensors_parts(DEEP, ("t_unix_s",), count=1),
        "invalid_field",
    ),
    ("sensor row too short", sensors_parts([[1.7e9]], ("t_unix_s", "humidity_pct")), "invalid_field"),
    ("sensor count wrong", sensors_parts([[1.7e9]], ("t_unix_s",), count=2), "invalid_field"),
    ("sensor a string", sensors_parts([[1.7e9, "x"]], ("t_unix_s", "zz")), "invalid_field"),
]


@pytest.mark.parametrize(("what", "frames", "reason"), CASES, ids=[c[0] for c in CASES])
def test_each_bad_message_is_refused_with_its_reason(what: str, frames: list[bytes], reason: str) -> None:
    with pytest.raises(wire.ProtocolError) as err:
        wire.decode(frames, allowed=wire.MODULE_TYPES)
    assert err.value.kind == reason, err.value.detail
    assert reason in wire.REASONS


def test_a_refusal_names_the_message_where_it_can() -> None:
    with pytest.raises(wire.ProtocolError) as err:
        wire.decode(frame_parts(gain_db=1e308))
    assert err.value.ref == {"type": "frame", "module": "A", "boot": "b1", "seq": 7}
    with pytest.raises(wire.ProtocolError) as err:  # ids that are not ids are not echoed
        wire.decode(frame_parts(boot="..", raw={"seq": str(2**63)}))
    assert "boot" not in err.value.ref and "seq" not in err.value.ref


def test_unknown_fields_and_unknown_sensor_columns_are_ignored() -> None:
    msg, _ = wire.decode(frame_parts(extra_field={"a": 1}))
    assert msg.seq == 7
    _, rows = wire.decode(sensors_parts([[1.7e9, 7.0, None]], ("t_unix_s", "future_sensor", "humidity_pct")))
    assert rows[0]["t_unix_s"] == 1.7e9 and rows[0]["humidity_pct"] is None and "future_sensor" not in rows[0]


def test_a_time_without_offset_is_utc_and_an_offset_is_converted() -> None:
    msg, _ = wire.decode(frame_parts(captured_at="2026-11-25T10:00:00"))
    assert msg.captured_at == datetime(2026, 11, 25, 10, tzinfo=UTC)
    msg, _ = wire.decode(frame_parts(captured_at="2026-11-25T12:00:00+02:00"))
    assert msg.captured_at == datetime(2026, 11, 25, 10, tzinfo=UTC)


def test_a_tiff_frame_is_checked_like_a_png() -> None:
    img = np.zeros((48, 64), np.uint8)
    ok, buf = cv2.imencode(".tiff", img)
    assert ok
    msg, _ = wire.decode(frame_parts(payload=buf.tobytes(), encoding="tiff"))
    assert msg.encoding == "tiff"
    ok, buf16 = cv2.imencode(".tiff", img.astype(np.uint16))
    with pytest.raises(wire.ProtocolError, match="16-bit"):
        wire.decode(frame_parts(payload=buf16.tobytes(), encoding="tiff"))


def test_the_dialect_limits() -> None:
    assert dialect.loads(b'{"a":[1,2.5,null]}', max_depth=2) == {"a": [1, 2.5, None]}
    assert dialect.loads(str(2**63 - 1).encode(), max_depth=0) == 2**63 - 1
    for bad in (b"NaN", b"[Infinity]", str(2**63).encode(), str(-(2**63) - 1).encode(), b"1e999", b"1" * 41):
        with pytest.raises(dialect.DialectError):
            dialect.loads(bad, max_depth=4)
    with pytest.raises(dialect.DialectError, match="deeper"):
        dialect.loads(b"[[[]]]", max_depth=2)
    with pytest.raises(ValueError):
        dialect.dumps(float("nan"))


def test_the_published_schema_is_generated_from_the_models() -> None:
    published = (REPO / "docs" / "protocol-v1.schema.json").read_text()
    assert published == schema_text(), (
        "regenerate: python -m camcal.core.wire.schema > docs/protocol-v1.schema.json"
    )


def test_the_protocol_document_names_every_reason_and_sensor_column() -> None:
    doc = (REPO / "docs" / "protocol.md").read_text()
    assert "protocol-v1.schema.json" in doc
    for reason in wire.REASONS:
        assert f"`{reason}`" in doc, reason
    for column in wire.SENSOR_COLUMNS:
        assert f"`{column}`" in doc, column


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=300), min_size=0, max_size=4))
def test_decoder_never_fails_other_than_with_protocol_error(frames: list[bytes]) -> None:
    with contextlib.suppress(wire.ProtocolError):
        wire.decode(frames)


json_values = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats()
    | st.text(max_size=20)
    | st.sampled_from(["..", "2026-11-25T00:00:00Z", "0001-01-01T00:00:00Z", "A", "b1"]),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=10), children, max_size=4)
    ),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(sorted(wire.MODULE_TYPES | wire.SHIP_TYPES)),
    st.dictionaries(
        st.sampled_from(
            [
                "module",
                "boot",
                "seq",
                "size",
                "sha256",
                "window",
                "ranges",
                "count",
                "columns",
                "action",
                "state",
                "exposure_s",
                "captured_at",
                "width_px",
            ]
        ),
        json_values,
        max_size=6,
    ),
    st.one_of(st.none(), st.binary(max_size=64)),
)
def test_structured_fuzz_only_protocol_errors(kind: str, fields: dict, payload: bytes | None) -> None:
    header = json.dumps({"v": 1, "type": kind, **fields}).encode()  # may hold NaN/Infinity: refused
    frames = [header] if payload is None else [header, payload]
    with contextlib.suppress(wire.ProtocolError):
        wire.decode(frames)


def test_the_protocol_document_lists_every_numbered_rule() -> None:
    """The conformance kits print rule numbers: each is the document's, with the same words."""
    from camcal.core.wire.rules import RULES

    doc = (REPO / "docs" / "protocol.md").read_text()
    rows = [
        ln for ln in doc.split("## The rules", 1)[1].splitlines() if ln.startswith("| ") and ln[2].isdigit()
    ]
    assert rows == [f"| {r.number} | {r.binds} | {r.title} |" for r in RULES]
