"""Conformance of a real ``camcal ingest`` process: every bad message answered, none can stop it.

A well-behaved module (A) streams beside a rogue client (R) that sends each
malformed case of the protocol, then messages that are well formed but
wrong (a conflicting resend, a jump to the largest sequence number, a
foreign module id, a bye). The ingest must answer each with its documented
reason, stay up, lose nothing of A, keep its event log valid JSON, and keep
counters that add up, across a restart.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator

import numpy as np
import pytest

from camcal.core import wire
from tests.live.test_ingest import wait_for
from tests.test_wire import CASES
from tests.utils.live import make_agent, stop_and_drain
from tests.utils.pace import Pace
from tests.utils.rogue import IngestProbe, Rogue, invalid_json_events
from tests.utils.wiremsgs import frame_parts, png_bytes, sensors_parts

BIGGEST = 2**63 - 1


def as_module(parts: list[bytes], module: str) -> list[bytes]:
    """The same message under another module id (the cases are written for A)."""
    return [parts[0].replace(b'"module": "A"', f'"module": "{module}"'.encode()), *parts[1:]]


@pytest.fixture(scope="module")
def ship(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[IngestProbe, object]]:
    root = tmp_path_factory.mktemp("conformance")
    probe = IngestProbe(root / "data")
    probe.wait_ready()
    agent, _ = make_agent("A", probe.endpoint, root / "outbox-A", keys_dir=probe.keys)
    agent.start()
    yield probe, agent
    agent.stop()
    probe.stop()


def greet(rogue: Rogue, module: str, boot: str = "k") -> None:
    """Say hello (data before a welcome is refused as ``no_hello``)."""
    hello = json.dumps({"v": 1, "type": "hello", "module": module, "boot": boot}).encode()
    assert [m.type for m in rogue.send([hello])] == ["welcome"]


def nacks(rogue: Rogue) -> list[wire.Nack]:
    return [r for r in rogue.replies if r.type == "nack"]


def test_each_malformed_case_gets_its_nack_and_the_ingest_goes_on(ship) -> None:
    probe, agent = ship
    rogue = probe.rogue("R")
    try:
        greet(rogue, "R")
        for what, parts, reason in CASES:
            replies = rogue.send(as_module(parts, "R"))
            assert [(r.type, r.reason) for r in replies] == [("nack", reason)], what
            assert replies[0].retry == wire.REASONS[reason].retry
        assert probe.alive()
        # A header no module id could even be read from, from a socket with no routing id of ours.
        anon = probe.rogue("anonymous-socket")
        assert [r.reason for r in anon.send([b'{"v":1,"x":' + b"[" * 30000 + b"]" * 30000 + b"}"])] == [
            "bad_header"
        ]
        anon.close()
        assert wait_for(lambda: agent.counters["acked"] >= 6, 30), "the good module stalled"
    finally:
        rogue.close()


def test_well_formed_but_wrong_messages_get_one_true_answer(ship) -> None:
    probe, _ = ship
    r = probe.rogue("R2")
    try:
        assert [
            m.type
            for m in r.send(
                as_module([json.dumps({"v": 1, "type": "hello", "module": "A", "boot": "k"}).encode()], "R2")
            )
        ] == ["welcome"]
        first = as_module(frame_parts(boot="k", seq=1), "R2")
        assert _acked(r.send(first), "k", 1)
        again = r.send(first)  # a resend of the same bytes: acknowledged again, stored once
        assert _acked(again, "k", 1)
        other = as_module(frame_parts(boot="k", seq=1, image=np.full((48, 64), 99, np.uint8)), "R2")
        (reply,) = r.send(other)
        assert (reply.type, reply.reason, reply.boot, reply.seq, reply.retry) == (
            "nack",
            "conflict",
            "k",
            1,
            False,
        )
        stored = probe.rows("SELECT sha256 FROM frames WHERE module_id='R2' AND boot='k' AND seq=1")
        assert stored == [(wire.sha256_hex(png_bytes()),)], "the first copy must be kept"
        assert wait_for(
            lambda: probe.rows("SELECT severity FROM alarms WHERE key='conflict:R2' AND active"), 5
        )

        pace = Pace()
        t0 = time.monotonic()
        assert _acked(r.send(as_module(frame_parts(boot="k", seq=BIGGEST), "R2")), "k", BIGGEST)
        assert _acked(r.send(as_module(frame_parts(boot="k", seq=2), "R2")), "k", 2)
        took_s = time.monotonic() - t0  # walking 2^63 sequence numbers one by one would never end
        assert took_s < pace.bound(5), f"a jump to the largest seq took {took_s:.1f} s ({pace})"
        gaps = probe.rows("SELECT first_seq, last_seq FROM gaps WHERE module_id='R2' AND boot='k'")
        assert gaps == [(2, BIGGEST - 1)], gaps

        null_t = as_module(sensors_parts([[None, 4.0]], ("t_unix_s", "temperature_c"), boot="k", seq=3), "R2")
        replies = r.send(null_t, wait_s=1.5, expect=2)
        assert [(m.type, m.reason) for m in replies] == [("nack", "invalid_field")], "a nack and nothing else"
        assert (replies[0].boot, replies[0].seq) == ("k", 3)

        (reply,) = r.send(as_module(frame_parts(boot="k", seq=4, sha256="0" * 64), "R2"))
        assert (reply.reason, reply.boot, reply.seq, reply.retry) == ("bad_payload", "k", 4, True)
        (reply,) = r.send(as_module(frame_parts(boot="k", seq=5), "someone-else"))
        assert reply.reason == "wrong_identity"
        status = {
            "v": 1,
            "type": "command_status",
            "module": "R2",
            "boot": "k",
            "command_id": "nope",
            "state": "done",
        }
        (reply,) = r.send([json.dumps(status).encode()])
        assert reply.reason == "invalid_field" and "nope" in reply.detail

        bye = json.dumps({"v": 1, "type": "bye", "module": "R2", "boot": "k"}).encode()
        assert r.send([bye], wait_s=0.5) == []
        assert wait_for(lambda: _alarm(probe, "signed_off:R2") == ("INFO", 1), 5)
        time.sleep(3.0)  # an alarm is one row that changes state, not a row (or an event) per second
        assert _alarm(probe, "signed_off:R2") == ("INFO", 1)
        assert _alarm(probe, "link_lost:R2") is None
        raised = probe.rows("SELECT COUNT(*) FROM events WHERE kind='alarm' AND module_id='R2'")[0][0]
        assert raised == 2, "one event for the conflict, one for the sign-off"
        assert probe.alive()
    finally:
        r.close()


def _acked(replies: list, boot: str, seq: int) -> bool:
    return any(m.type == "ack" and any(b == boot and a <= seq <= z for b, a, z in m.ranges) for m in replies)


def _alarm(probe: IngestProbe, key: str) -> tuple[str, int] | None:
    rows = probe.rows("SELECT severity, COUNT(*) FROM alarms WHERE key=? GROUP BY severity", key)
    return tuple(rows[0]) if rows else None


def test_a_message_that_fails_twice_while_others_are_stored_is_quarantined(ship) -> None:
    probe, _ = ship
    # A fault that hits one boot's messages only: its frame folder is taken by a plain file.
    dive_id = probe.rows("SELECT id FROM dives ORDER BY id DESC LIMIT 1")[0][0]
    blocker = probe.data / "frames" / str(dive_id) / "Q" / "bad"
    blocker.parent.mkdir(parents=True, exist_ok=True)
    blocker.write_text("not a folder")
    q = probe.rogue("Q")
    try:
        greet(q, "Q")
        poisoned = as_module(frame_parts(boot="bad", seq=1), "Q")
        (reply,) = q.send(poisoned)
        assert (reply.reason, reply.retry) == ("internal_error", True)
        assert _acked(q.send(as_module(frame_parts(boot="good", seq=1), "Q")), "good", 1)
        (reply,) = q.send(poisoned)  # failed again, and others were stored meanwhile: kept aside
        assert (reply.reason, reply.retry) == ("quarantined", False)
        (reply,) = q.send(poisoned)  # from now on refused at once, never retried into a crash loop
        assert reply.reason == "quarantined"
        kept = list((probe.data / "quarantine").glob("*-Q-bad-1-*.json"))
        assert len(kept) == 1
        assert json.loads(kept[0].read_text())["header"]["sha256"] == wire.sha256_hex(png_bytes())
        assert kept[0].with_suffix(".bin").read_bytes() == png_bytes()
        assert _acked(q.send(as_module(frame_parts(boot="good", seq=2), "Q")), "good", 2)
        assert probe.alive()
    finally:
        q.close()


def test_counters_add_up_events_are_json_and_nothing_of_the_good_module_is_lost(ship) -> None:
    """Last in this file: it restarts the ingest."""
    probe, agent = ship
    rogue = probe.rogue("R3")
    for _, parts, _ in CASES[:10]:
        rogue.send(as_module(parts, "R3"))
    refused_here = len(nacks(rogue))
    assert refused_here == 10
    rogue.close()
    h = probe.health()
    c = h["counters"]
    assert c["malformed"] == sum(h["malformed"].values())
    assert c["nacked"] == sum(h["nacked"].values())
    assert c["nacked"] >= c["malformed"] >= refused_here
    assert stop_and_drain([agent]), agent.outbox.pending_count()
    stored = probe.rows("SELECT COUNT(*) FROM frames WHERE module_id='A'")[0][0]
    assert stored == agent.counters["frames_captured"] > 0 and agent.counters["nacked"] == 0
    assert list(invalid_json_events(probe)) == []
    # Every stored frame has its event (written in the frame's own transaction).
    orphans = probe.rows(
        "SELECT COUNT(*) FROM frames f WHERE NOT EXISTS (SELECT 1 FROM events e WHERE e.kind='frame' "
        "AND json_extract(e.payload, '$.frame_id') = f.id)"
    )[0][0]
    assert orphans == 0
    # The counters survive a restart of the ingest (same data folder, same address: same ingest id).
    before = probe.health()["counters"]
    assert probe.stop() == 0
    restarted = IngestProbe(probe.data, ports=(probe.port, probe.events_port))
    try:
        after = restarted.health(30)["counters"]
        assert after["nacked"] >= before["nacked"] and after["malformed"] >= before["malformed"]
    finally:
        restarted.stop()
