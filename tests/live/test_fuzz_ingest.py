"""A real ``camcal ingest`` fuzzed from the published schema, and the minimal module of the docs.

The fuzzer builds headers from ``docs/protocol-v1.schema.json`` (what a
stranger's module could send from the schema alone), gives data messages
payloads that match or do not, and mixes in damaged bytes. For each
message it predicts the answer the protocol promises (a ``nack`` with the
reason, a ``welcome``, an ``ack``, or nothing for a heartbeat or a bye) and
checks the ingest gives exactly that, within two seconds (no hang). At the
end the ingest is alive and its counters equal the refusals seen.

``make test`` sends 800 messages; ``CAMCAL_FUZZ_MESSAGES=10000`` (``make
fuzz``) is the slow lane.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from camcal.core import wire
from camcal.core.wire.keys import create_module_key
from tests.utils.live import cli_env
from tests.utils.rogue import IngestProbe, invalid_json_events
from tests.utils.schema_strategies import strategy

REPO = Path(__file__).resolve().parents[2]
SCHEMA = json.loads((REPO / "docs" / "protocol-v1.schema.json").read_text())
MESSAGES = int(os.environ.get("CAMCAL_FUZZ_MESSAGES", "800"))
MODULE = "F"
NAMES = {
    "hello": "Hello",
    "frame": "FrameMsg",
    "sensors": "SensorsMsg",
    "heartbeat": "ModuleHeartbeat",
    "command_status": "CommandStatus",
    "bye": "Bye",
}


def header_of(kind: str) -> st.SearchStrategy[dict[str, Any]]:
    return strategy(SCHEMA["$defs"][NAMES[kind]], SCHEMA["$defs"]).map(
        lambda h: {**h, "v": 1, "type": kind, "module": MODULE}
    )


def chance(draw: st.DrawFn, one_in: int) -> bool:
    """True once in ``one_in`` draws or so; False is the simplest value, so shrinking heads to valid."""
    return draw(st.integers(0, one_in - 1)) == one_in - 1


IN_WINDOW = st.datetimes(datetime(2020, 1, 1), datetime(2040, 1, 1), timezones=st.just(UTC)).map(
    lambda d: d.isoformat().replace("+00:00", "Z")
)


@st.composite
def messages(draw: st.DrawFn) -> list[bytes]:
    """One message: a schema-made header (times mostly in the ship's window), a payload that mostly
    matches it, sometimes damaged bytes."""
    kind = draw(st.sampled_from(sorted(NAMES)))
    header = draw(header_of(kind))
    for key in ("sent_at", "captured_at"):
        if key in header and not chance(draw, 4):
            header[key] = draw(IN_WINDOW)
    payload = None
    if kind == "frame":
        header["width_px"] = draw(st.integers(1, 40)) if not chance(draw, 5) else header["width_px"]
        header["height_px"] = draw(st.integers(1, 40)) if not chance(draw, 5) else header["height_px"]
        if not chance(draw, 4):
            img = np.full((min(header["height_px"], 40), min(header["width_px"], 40)), 9, np.uint8)
            payload = cv2.imencode(".png", img)[1].tobytes()
            header["encoding"] = "png"
        else:
            payload = draw(st.binary(min_size=1, max_size=64))
    elif kind == "sensors":
        if not chance(draw, 4):
            header["columns"] = list(wire.SENSOR_COLUMNS[: draw(st.integers(1, 10))])
        ncol = len(header.get("columns", wire.SENSOR_COLUMNS))
        row = st.lists(
            st.floats(1.7e9, 1.8e9) | st.floats(-1e3, 1e3) | st.none(), min_size=ncol, max_size=ncol
        )
        rows = draw(st.lists(row, max_size=3))
        payload = json.dumps(rows).encode()
        header["count"] = len(rows) if not chance(draw, 5) else header["count"]
    if payload is not None and not chance(draw, 8):  # mostly a header that matches its payload
        header["size"], header["sha256"] = len(payload), wire.sha256_hex(payload)
    text = json.dumps(header).encode()
    if chance(draw, 10):  # flip or cut bytes of the header
        cut = draw(st.integers(0, len(text)))
        text = text[:cut] + draw(st.binary(max_size=8)) + text[cut + 1 :]
    parts = [text] if payload is None else [text, payload]
    if chance(draw, 12):  # or send noise
        parts = draw(st.lists(st.binary(max_size=40), min_size=1, max_size=3))
    return parts


class Oracle:
    """What the ship must answer, from the protocol: ``(type, nack reason)``, or None for no answer."""

    def __init__(self, dive: str) -> None:
        self.dive = dive  # the dive the ship records: a message naming another is refused
        self.stored: dict[tuple[str, int], str] = {}  # (boot, seq) -> content checksum of what was acked
        self.boot: str | None = None  # the boot the module's link is at (None: no link yet)
        self.welcomed = False  # a hello (or a heartbeat) was welcomed since the last bye

    def is_data(self, parts: list[bytes]) -> bool:
        """A frame or sensors message of this module and dive (what the ship's link admits or not)."""
        try:
            msg, _ = wire.decode_header(parts, allowed=wire.MODULE_TYPES)
        except wire.ProtocolError:
            return False
        ours = msg.module == MODULE and (msg.dive is None or msg.dive == self.dive)
        return ours and msg.type in ("frame", "sensors")

    def answered(self, parts: list[bytes], got: tuple[str, str | None]) -> None:
        """What the ship's answer to a data message tells: stored (ack), or its link had lapsed."""
        msg, _ = wire.decode_header(parts, allowed=wire.MODULE_TYPES)
        if got == ("ack", None):
            self.stored.setdefault((msg.boot, msg.seq), wire.content_sha256(msg))
        elif got == ("nack", "no_hello"):
            # a run of messages refused before the link (wrong dive, malformed: they do not keep a link
            # up) outlasted the ship's link timeout: the link lapsed and wants a hello again
            self.welcomed = False

    def expected(self, parts: list[bytes]) -> tuple[str, str | None] | None:
        # In the document's order: the header, the sender, the dive, then a data message's payload.
        try:
            msg, _ = wire.decode_header(parts, allowed=wire.MODULE_TYPES)
        except wire.ProtocolError as exc:
            return ("nack", exc.kind)
        if msg.module != MODULE:
            return ("nack", "wrong_identity")
        if msg.dive is not None and msg.dive != self.dive:
            return ("nack", "wrong_dive")
        if msg.type in ("frame", "sensors") and not self.welcomed:
            return ("nack", "no_hello")  # data before a hello (protocol 1.9), before its payload is read
        try:
            wire.decode(parts, allowed=wire.MODULE_TYPES)
        except wire.ProtocolError as exc:
            return ("nack", exc.kind)
        boot = getattr(msg, "boot", "")
        if self.boot is None:  # the link is made by the module's first message that passes the above
            self.boot = boot
        if msg.type == "hello":
            self.boot, self.welcomed = boot, True
            return ("welcome", None)
        if msg.type in ("frame", "sensors"):
            content = wire.content_sha256(msg)  # every header field but the transport's, and the payload's
            first = self.stored.get((msg.boot, msg.seq), content)
            return ("ack", None) if first == content else ("nack", "conflict")
        if msg.type == "command_status":
            return ("nack", "invalid_field")  # no such command was sent to this module
        if msg.type == "bye":
            if boot != self.boot:  # another boot's goodbye: refused, the module stays linked (1.9)
                return ("nack", "invalid_field")
            self.welcomed = False
            return None  # its own boot's: accepted without a word
        self.boot, self.welcomed = boot, True  # a heartbeat: greeted with a welcome if it was not
        return None


@pytest.fixture(scope="module")
def fuzz_ship(tmp_path_factory: pytest.TempPathFactory) -> Iterator[IngestProbe]:
    probe = IngestProbe(tmp_path_factory.mktemp("fuzz") / "data")
    probe.wait_ready()
    yield probe
    probe.stop()


def test_fuzzed_messages_get_the_promised_answer_and_the_counters_add_up(fuzz_ship: IngestProbe) -> None:
    probe = fuzz_ship
    rogue = probe.rogue(MODULE)
    health = probe.health()
    before = health["counters"].get("nacked", 0)
    seen: Counter[str] = Counter()
    oracle = Oracle(health["dive"]["name"])

    @settings(max_examples=MESSAGES, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(messages())
    def one(parts: list[bytes]) -> None:
        want = oracle.expected(parts)
        skip = ("ship_heartbeat",) if want and want[0] == "welcome" else ("ship_heartbeat", "welcome")
        got = rogue.send(parts, wait_s=2.0 if want else 0.0, expect=1 if want else 0, skip=skip)
        seen[want[1] or want[0] if want else "silent"] += 1
        if want is None:
            return
        assert got, f"no answer in 2 s to {parts[0][:200]!r} (expected {want})"
        pair = (got[0].type, getattr(got[0], "reason", None))
        if oracle.is_data(parts) and want != ("nack", "no_hello"):
            oracle.answered(parts, pair)
            if pair == ("nack", "no_hello"):
                return
        assert pair == want, (parts[0][:300], got[0])

    try:  # the socket closed however this ends (left open, it warns in a later test of this worker)
        one()
        assert probe.alive(), "the ingest died"
        late = rogue.collect(1.0, expect=10**6)
        assert [m for m in late if m.type != "welcome"] == [], f"answers nobody asked for: {late[:3]}"
    finally:
        rogue.close()
    health = probe.health()
    c = health["counters"]
    assert c["nacked"] == sum(health["nacked"].values()) and c["malformed"] == sum(
        health["malformed"].values()
    )
    nacked_here = sum(1 for r in rogue.replies if r.type == "nack")
    assert c["nacked"] - before == nacked_here, (c["nacked"], before, nacked_here, seen)
    assert list(invalid_json_events(probe)) == []
    print(f"fuzz: {MESSAGES} messages, answers {dict(seen)}")


def test_the_minimal_module_in_the_docs_delivers_everything(fuzz_ship: IngestProbe) -> None:
    example = REPO / "docs" / "examples" / "minimal_module.py"
    create_module_key(fuzz_ship.keys, "MIN")
    args = [fuzz_ship.endpoint, "--module", "MIN", "--frames", "6", "--keys", str(fuzz_ship.keys)]
    res = subprocess.run(
        [sys.executable, str(example), *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=cli_env(),
    )
    assert res.returncode == 0, res.stdout + res.stderr
    assert json.loads(res.stdout) == {"unacknowledged": [], "refused": {}}
    frames = fuzz_ship.rows("SELECT seq, path, sha256 FROM frames WHERE module_id='MIN' ORDER BY seq")
    assert [f[0] for f in frames] == [1, 2, 3, 4, 5, 6]
    for _, path, sha in frames:
        assert wire.sha256_hex((fuzz_ship.data / path).read_bytes()) == sha
    assert fuzz_ship.rows("SELECT COUNT(*) FROM sensor_batches WHERE module_id='MIN'") == [(1,)]
