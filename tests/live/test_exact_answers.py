"""Every answer is exact (issue 38, items 2-4 and 6, and the window and hello rules), on a real ingest.

One ``camcal ingest`` process, clients over CURVE on real sockets. What another
lab's module found by experiment: a malformed id told to resend for ever, a
version ``1.0`` taken, a resend with another header acknowledged and its change
dropped, a ``bye`` for another boot signing the module off, a bare routing id
that anyone could take over, data before ``hello`` and beyond the window
taken, and refused connections logged once per key without their address.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zmq

from camcal.core import wire
from tests.live.test_ingest import wait_for
from tests.utils.rogue import IngestProbe, Rogue
from tests.utils.wiremsgs import T0, frame_parts, png_bytes, sensors_parts


@pytest.fixture(scope="module")
def probe(tmp_path_factory: pytest.TempPathFactory) -> Iterator[IngestProbe]:
    p = IngestProbe(tmp_path_factory.mktemp("exact") / "data")
    p.wait_ready()
    yield p
    p.stop()


def header(**fields: Any) -> list[bytes]:
    return [json.dumps({"v": 1, **fields}).encode()]


def answers(replies: list[Any]) -> list[tuple[str, str | None]]:
    return [(m.type, getattr(m, "reason", None)) for m in replies]


def test_a_malformed_id_is_refused_for_good_once(probe: IngestProbe) -> None:
    """A boot ending in a newline was ``internal_error, retry: true`` (resend for ever), counted twice."""
    r = probe.rogue("M1")
    try:
        bad = "B\n"
        cases = [
            header(type="hello", module="M1", boot=bad),
            header(type="heartbeat", module="M1", boot=bad),
            header(type="bye", module="M1", boot=bad),
            frame_parts(module="M1", camera="A", boot=bad, seq=1),
            sensors_parts([[1.8e9, 4.0]], ("t_unix_s", "temperature_c"), module="M1", boot=bad, seq=2),
        ]
        before = probe.health()["counters"]
        for parts in cases:
            replies = r.send(parts, wait_s=1.5, expect=2)
            assert [(m.type, m.reason, m.retry) for m in replies] == [("nack", "invalid_field", False)]
            assert "boot" in replies[0].detail
        after = probe.health()["counters"]
        assert after["nacked"] - before.get("nacked", 0) == len(cases), "each refusal counted once"
        assert after.get("internal_error", 0) == before.get("internal_error", 0)
        assert probe.health()["nacked"].get("internal_error", 0) == 0
    finally:
        r.close()


def test_a_version_written_as_a_fraction_is_refused(probe: IngestProbe) -> None:
    r = probe.rogue("M2")
    try:
        assert answers(r.send(header(type="hello", module="M2", boot="k"))) == [("welcome", None)]
        parts = frame_parts(module="M2", camera="A", boot="k", seq=1, raw={"v": "1.0"})
        assert answers(r.send(parts)) == [("nack", "bad_version")]
        assert probe.rows("SELECT COUNT(*) FROM frames WHERE module_id='M2'") == [(0,)]
    finally:
        r.close()


def test_a_resend_with_another_header_is_a_conflict_and_the_first_is_kept(probe: IngestProbe) -> None:
    r = probe.rogue("M3")
    try:
        assert answers(r.send(header(type="hello", module="M3", boot="k"))) == [("welcome", None)]
        first = dict(module="M3", camera="A", boot="k", seq=1)
        assert answers(r.send(frame_parts(**first))) == [("ack", None)]
        later = (T0.replace(minute=5)).isoformat()
        resend = frame_parts(**first, sent_at=later)  # the same message sent again later: a resend
        assert answers(r.send(resend)) == [("ack", None)]
        for change in ({"wavelength_nm": 520}, {"captured_at": later}, {"exposure_s": 0.1}):
            replies = r.send(frame_parts(**first, **change))
            assert [(m.type, m.reason, m.seq, m.retry) for m in replies] == [("nack", "conflict", 1, False)]
        rows = probe.rows("SELECT wavelength_nm, exposure_s FROM frames WHERE module_id='M3' AND seq=1")
        assert rows == [(460, 0.05)], "the first copy is kept"
        assert wait_for(lambda: probe.rows("SELECT 1 FROM alarms WHERE key='conflict:M3' AND active"), 10)
        # Sensor rows: the same payload under other columns is other data.
        rows_in = [[1.8e9, 4.0]]
        sens = dict(module="M3", boot="k", seq=2)
        assert answers(r.send(sensors_parts(rows_in, ("t_unix_s", "temperature_c"), **sens))) == [
            ("ack", None)
        ]
        assert answers(r.send(sensors_parts(rows_in, ("t_unix_s", "humidity_pct"), **sens))) == [
            ("nack", "conflict")
        ]
    finally:
        r.close()


def test_a_bye_for_another_boot_does_not_sign_the_module_off(probe: IngestProbe) -> None:
    r = probe.rogue("M4")
    try:
        assert answers(r.send(header(type="hello", module="M4", boot="now"))) == [("welcome", None)]
        replies = r.send(header(type="bye", module="M4", boot="before"))
        assert answers(replies) == [("nack", "invalid_field")]
        assert "now" in replies[0].detail
        assert probe.health()["modules"]["M4"]["link"] == "up"
        assert r.send(header(type="bye", module="M4", boot="now"), wait_s=0.5) == []
        assert wait_for(lambda: probe.health()["modules"]["M4"]["link"] == "signed_off", 10)
    finally:
        r.close()


def test_a_bare_routing_id_is_refused(probe: IngestProbe) -> None:
    """A route anyone can guess (the bare module id) could be taken over by a holder of another key."""
    r = probe.rogue("M5", route=b"M5")
    try:
        replies = r.send(header(type="hello", module="M5", boot="k"))
        assert answers(replies) == [("nack", "wrong_identity")]
        assert "random" in replies[0].detail
        short = probe.rogue("M5", route=b"M5/1234")  # guessable too
        assert answers(short.send(header(type="hello", module="M5", boot="k"))) == [
            ("nack", "wrong_identity")
        ]
        short.close()
    finally:
        r.close()


def test_data_before_hello_and_beyond_the_window_is_refused(probe: IngestProbe) -> None:
    r = probe.rogue("M6")
    try:
        replies = r.send(frame_parts(module="M6", camera="A", boot="k", seq=1))
        assert [(m.type, m.reason, m.retry) for m in replies] == [("nack", "no_hello", True)]
        welcome = r.send(header(type="hello", module="M6", boot="k"))
        assert answers(welcome) == [("welcome", None)]
        window = welcome[0].window
        n = 5 * window
        for seq in range(1, n + 1):  # all at once, not waiting for answers
            img = np.full((48, 64), seq % 250, np.uint8)
            r.sock.send_multipart(frame_parts(module="M6", camera="A", boot="k", seq=seq, image=img))
        got = r.collect(60, expect=n)
        settled: dict[int, list[str]] = {}
        for m in got:
            if m.type == "ack":
                for _, a, z in m.ranges:
                    for q in range(a, z + 1):
                        settled.setdefault(q, []).append("ack")
            else:
                settled.setdefault(m.seq, []).append(m.reason)
        assert sorted(settled) == list(range(1, n + 1)) and all(len(v) == 1 for v in settled.values())
        over = [q for q, v in settled.items() if v == ["over_window"]]
        acked = [q for q, v in settled.items() if v == ["ack"]]
        assert over and len(acked) + len(over) == n, settled
        assert all(m.retry for m in got if m.type == "nack")
    finally:
        r.close()


def test_refused_connections_are_logged_per_source_with_its_address(probe: IngestProbe) -> None:
    log = probe.data.parent / "ingest.log"
    start = len(log.read_text().splitlines())
    ctx = zmq.Context.instance()
    ghosts = [
        Rogue(ctx, probe.endpoint, f"ghost{i}", keys_dir=probe.keys, pair=_random_pair()) for i in range(40)
    ]
    plain = Rogue(ctx, probe.endpoint, "plain")  # no CURVE at all
    try:
        for g in ghosts:
            g.send(header(type="hello", module=g.sock.get(zmq.ROUTING_ID).decode(), boot="k"), wait_s=0.05)
        plain.send(header(type="hello", module="plain", boot="k"), wait_s=0.5)
        assert wait_for(lambda: probe.health()["refused_connections"]["total"] >= 41, 20)
        time.sleep(0.5)
    finally:
        for g in [*ghosts, plain]:
            g.close()
    lines = [ln for ln in log.read_text().splitlines()[start:] if "refused a connection" in ln]
    unknown = [ln for ln in lines if "unknown_key" in ln]
    assert 1 <= len(unknown) <= 2, unknown  # one line, then at most one every ten seconds per source
    plaintext = [ln for ln in lines if "plaintext" in ln or "no_handshake" in ln]
    # A plaintext client retries every 0.1 s; a try whose connection was gone before the receiving
    # thread read its address (a busy machine) is logged "from an unknown address": never a wrong one.
    assert any("127.0.0.1" in ln for ln in plaintext), plaintext
    assert all("127.0.0.1" in ln or "an unknown address" in ln for ln in plaintext), plaintext


def _random_pair() -> wire.KeyPair:
    public, secret = zmq.curve_keypair()
    return wire.KeyPair(public, secret)


def test_the_image_of_a_conflict_is_never_overwritten(probe: IngestProbe) -> None:
    """(The first copy's file stays: the store keeps the first, whatever the header of the second.)"""
    rows = probe.rows("SELECT sha256 FROM frames WHERE module_id='M3' AND seq=1")
    assert rows == [(wire.sha256_hex(png_bytes()),)]
