"""The reference module's answer to a refusal: resend with back-off if that can help, else keep it aside."""

from __future__ import annotations

import itertools
import json
import time
from collections import Counter
from pathlib import Path

import zmq

from camcal.core import wire
from camcal.core.frameset import read_manifest
from lrm.agent import MAX_RESENDS
from lrm.outbox import Outbox
from tests.lrm.test_agent_commands import Module, schedule
from tests.utils.live import FakeShip


def nack(msg, reason: str) -> wire.Nack:
    return wire.Nack(
        module="ship",
        boot=msg.boot,
        seq=msg.seq,
        of=msg.type,
        reason=reason,
        retry=wire.REASONS[reason].retry,
    )


def test_a_refusal_that_resending_cannot_help_is_kept_on_the_card_and_never_sent_again(
    tmp_path: Path,
) -> None:
    ship = FakeShip(zmq.Context.instance())
    refused_seq = 3
    ship.answer = lambda m: nack(m, "invalid_field") if m.seq == refused_seq else None
    m = Module(tmp_path / "outbox", ship.endpoint, schedule(1))
    try:
        assert ship.pump(lambda: m.agent.counters["refused"] >= 1, 15)
        ship.answer = None  # from now on acknowledge everything
        assert ship.pump(lambda: m.agent.counters["acked"] >= 6, 20)
        sends = Counter((b, q) for kind, b, q in ship.data)
        assert sends[(m.agent.boot, refused_seq)] == 1, "a refused message must not be sent again"
    finally:
        m.stop()
        ship.close()
    lines = [json.loads(x) for x in (tmp_path / "outbox" / "refused.jsonl").read_text().splitlines()]
    assert [(x["seq"], x["reason"]) for x in lines] == [(refused_seq, "invalid_field")]
    box = Outbox(tmp_path / "outbox", "A", fsync=False)  # after a reboot it is still settled...
    assert box.get(lines[0]["boot"], refused_seq) is None
    assert refused_seq not in {e.seq for e in box.pending()}
    box.close()
    rows = read_manifest(tmp_path / "outbox" / "frames")  # ...and still on the card for `camcal import`
    assert any(r.seq == refused_seq and r.boot == lines[0]["boot"] for r in rows)


def test_a_retryable_refusal_is_resent_with_back_off_then_given_up(tmp_path: Path) -> None:
    ship = FakeShip(zmq.Context.instance())
    times: list[float] = []

    def answer(msg):
        if msg.seq == 1:
            times.append(time.monotonic())
            return nack(msg, "internal_error")
        return wire.Ack(module="ship", ranges=((msg.boot, msg.seq, msg.seq),), window=8)

    ship.answer = answer
    m = Module(tmp_path / "outbox", ship.endpoint, schedule(1))
    try:
        assert ship.pump(lambda: len(times) >= 3, 20)
        gaps = [b - a for a, b in itertools.pairwise(times)]
        assert gaps[0] >= 0.9 and gaps[1] >= 1.9, gaps  # 1 s, then 2 s
        assert m.agent.counters["acked"] >= 2, "the other messages go on meanwhile"
    finally:
        m.stop()
        ship.close()
    assert MAX_RESENDS >= 3


def test_not_served_sends_the_module_back_to_saying_hello(tmp_path: Path) -> None:
    ship = FakeShip(zmq.Context.instance())
    ship.answer = lambda msg: nack(msg, "not_served")
    m = Module(tmp_path / "outbox", ship.endpoint, schedule(1))
    try:
        assert ship.pump(lambda: m.agent.counters["nacked_not_served"] >= 1, 15)
        hellos = len(ship.hellos)
        assert ship.pump(lambda: len(ship.hellos) >= hellos + 1, 5), "it must greet the ship again"
        assert m.agent.counters["refused"] == 0 and m.agent.outbox.pending_count() > 0
    finally:
        m.stop()
        ship.close()


def test_a_hung_link_loop_stops_feeding_the_watchdog(tmp_path: Path) -> None:
    """`Agent.alive` (what `camcal lrm run` feeds systemd's watchdog on) turns false when the link
    loop stops going round, so that systemd restarts a module that hangs."""
    import threading

    ship = FakeShip(zmq.Context.instance())
    m = Module(tmp_path / "outbox", ship.endpoint, schedule(1))
    release = threading.Event()
    try:
        assert ship.pump(lambda: m.agent.counters["acked"] >= 2, 15)
        assert m.agent.alive(within_s=1.0)
        watch = m.agent.check.watch
        m.agent.check.watch = lambda: (release.wait(30), watch())[1]  # the loop blocks in its next round
        time.sleep(1.5)
        assert not m.agent.alive(within_s=1.0)
        release.set()
        assert ship.pump(lambda: m.agent.alive(within_s=1.0), 5)
    finally:
        release.set()
        m.stop()
        ship.close()
