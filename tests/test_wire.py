"""The wire protocol: round trips, every kind of malformed message, and a fuzzed decoder."""

from __future__ import annotations

import contextlib
import json
from datetime import UTC, datetime

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from camcal import wire


def frame_message(payload: bytes = b"\x89PNG fake", **over) -> list[bytes]:
    header = wire.FrameMsg(
        module="A",
        boot="b1",
        seq=7,
        captured_at=datetime(2021, 9, 10, tzinfo=UTC),
        camera="A",
        wavelength_nm=460,
        exposure_s=0.05,
        gain_db=8.0,
        depth_m=3398.4,
        width_px=2448,
        height_px=2048,
        size=len(payload),
        sha256=wire.sha256_hex(payload),
    )
    obj = json.loads(header.model_dump_json())
    obj.update(over)
    return [json.dumps(obj).encode(), payload]


def test_round_trip_of_every_message_type() -> None:
    payload = b"abc"
    msgs = [
        (wire.Hello(module="A", boot="b1"), None),
        (wire.ModuleHeartbeat(module="A", boot="b1", outbox_pending=3), None),
        (
            wire.SensorsMsg(module="A", boot="b1", seq=2, count=1, size=3, sha256=wire.sha256_hex(payload)),
            payload,
        ),
        (wire.CommandStatus(module="A", boot="b1", command_id="c1", state="done"), None),
        (wire.Welcome(module="ship", window=8), None),
        (wire.Ack(module="ship", ranges=(("b1", 1, 5),), window=4), None),
        (wire.Nack(module="ship", boot="b1", seq=3, reason="checksum"), None),
        (wire.ShipHeartbeat(module="ship", window=8), None),
        (wire.Command(module="ship", command_id="c1", action="pause"), None),
        (wire.Bye(module="A", boot="b1"), None),
    ]
    for msg, pl in msgs:
        frames = [bytes(f) for f in wire.encode(msg, pl)]
        out, out_pl = wire.decode(frames)
        assert out == msg
        assert (bytes(out_pl) if out_pl is not None else None) == pl
    frame, pl = wire.decode(frame_message())
    assert frame.seq == 7 and frame.wavelength_nm == 460 and bytes(pl) == b"\x89PNG fake"


@pytest.mark.parametrize(
    ("frames", "kind"),
    [
        ([], "bad_framing"),
        ([b"{}", b"a", b"b"], "bad_framing"),
        ([b"not json"], "bad_header"),
        ([b"[1, 2]"], "bad_header"),
        ([json.dumps({"v": 2, "type": "hello", "module": "A", "boot": "b"}).encode()], "bad_version"),
        ([json.dumps({"v": 1, "type": "launch", "module": "A"}).encode()], "unknown_type"),
        ([json.dumps({"v": 1, "type": "hello", "module": "A B", "boot": "b"}).encode()], "invalid_field"),
        ([json.dumps({"v": 1, "type": "hello", "module": "A"}).encode()], "invalid_field"),
        (frame_message()[:1], "bad_framing"),
        (frame_message(exposure_s=-1), "invalid_field"),
        (frame_message(size=3), "bad_payload"),
        (frame_message(sha256="0" * 64), "bad_payload"),
        ([b"{" * (wire.MAX_HEADER_BYTES + 1)], "oversized"),
    ],
)
def test_malformed_messages_raise_protocol_errors_by_kind(frames, kind: str) -> None:
    with pytest.raises(wire.ProtocolError) as info:
        wire.decode(frames)
    assert info.value.kind == kind


def test_payload_size_limit_and_allowed_types() -> None:
    with pytest.raises(wire.ProtocolError, match="exceeds"):
        wire.decode(frame_message(b"x" * 100), max_payload_bytes=10)
    with pytest.raises(wire.ProtocolError, match="not accepted here"):
        wire.decode(
            [bytes(f) for f in wire.encode(wire.Welcome(module="ship", window=1))], allowed=wire.MODULE_TYPES
        )


def test_sensor_rows_are_checked() -> None:
    good = wire.sensors_payload([[1.0] * len(wire.SENSOR_COLUMNS)])
    msg = wire.SensorsMsg(module="A", boot="b", seq=1, count=1, size=len(good), sha256=wire.sha256_hex(good))
    assert wire.parse_sensor_rows(msg, good)[0]["t_unix_s"] == 1.0
    bad = wire.sensors_payload([[1.0, "x"]])
    with pytest.raises(wire.ProtocolError):
        wire.parse_sensor_rows(msg, bad)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.binary(max_size=300), min_size=0, max_size=4))
def test_decoder_never_fails_other_than_with_protocol_error(frames: list[bytes]) -> None:
    with contextlib.suppress(wire.ProtocolError):
        wire.decode(frames)


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda children: (
        st.lists(children, max_size=4) | st.dictionaries(st.text(max_size=10), children, max_size=4)
    ),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None)
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
                "action",
                "state",
                "exposure_s",
                "captured_at",
            ]
        ),
        json_values,
        max_size=6,
    ),
    st.one_of(st.none(), st.binary(max_size=64)),
)
def test_structured_fuzz_only_protocol_errors(kind: str, fields: dict, payload: bytes | None) -> None:
    header = json.dumps({"v": 1, "type": kind, **fields}).encode()
    frames = [header] if payload is None else [header, payload]
    with contextlib.suppress(wire.ProtocolError):
        wire.decode(frames)
