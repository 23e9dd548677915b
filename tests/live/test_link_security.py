"""The module link is authenticated: a real ``camcal ingest`` (CURVE) against a real module and intruders.

A well-behaved module A streams with its own key while others try their
luck on the same port: an impostor holding another module's key who says
it is A, a client with a key the ship does not know, a plaintext client,
and a flood of 200 hellos from unknown keys. Only A's key speaks for A; the
others are refused and counted, and show on the ingest's health as refused
connections, never as modules or alarms.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zmq

from camcal.core import wire
from camcal.core.wire.keys import KeyPair
from storage.store import Store
from tests.live.test_ingest import wait_for
from tests.utils.live import make_agent
from tests.utils.rogue import IngestProbe, Rogue
from tests.utils.wiremsgs import frame_parts


def hello(module: str, boot: str = "b1", **extra: object) -> list[bytes]:
    return [json.dumps({"v": 1, "type": "hello", "module": module, "boot": boot, **extra}).encode()]


def random_pair() -> KeyPair:
    public, secret = zmq.curve_keypair()
    return KeyPair(public, secret)


@pytest.fixture(scope="module")
def ship(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[IngestProbe, object]]:
    root = tmp_path_factory.mktemp("link")
    probe = IngestProbe(root / "data")
    probe.wait_ready()
    agent, _ = make_agent("A", probe.endpoint, root / "outbox-A", keys_dir=probe.keys, heartbeat_s=0.3)
    agent.start()
    assert wait_for(lambda: agent.counters["acked"] >= 2, 30), "module A never got through"
    yield probe, agent
    agent.stop()
    probe.stop()


def test_an_impostor_with_another_modules_key_is_refused_and_a_gets_its_own_commands_and_acks(ship) -> None:
    probe, agent = ship
    impostor = probe.rogue("A", key_of="B")  # B's key, A's id in its routing id and in every header
    try:
        (reply,) = impostor.send(hello("A"))
        assert (reply.type, reply.reason) == ("nack", "wrong_identity")
        assert "belongs to module 'B'" in reply.detail
        (reply,) = impostor.send(frame_parts(boot="forged", seq=1))
        assert (reply.type, reply.reason, reply.boot, reply.seq) == ("nack", "wrong_identity", "forged", 1)
        assert probe.rows("SELECT COUNT(*) FROM frames WHERE boot='forged'") == [(0,)]
        # An operator's commands for A while the impostor is connected: they reach A, and only A.
        store = Store.open(probe.data, run_migrations=False)
        try:
            for i in range(3):
                store.create_command(f"cmd-{i}", "A", "pause" if i % 2 == 0 else "resume", "deck")
        finally:
            store.close()
        assert wait_for(lambda: all(f"cmd-{i}" in agent._commands for i in range(3)), 20)
        acked = agent.counters["acked"]
        assert wait_for(lambda: agent.counters["acked"] > acked, 20), "A's acknowledgements stopped"
        later = impostor.collect(2.0, expect=10**6, skip=())
        got = {m.type for m in impostor.replies + later}
        assert "command" not in got and "ack" not in got and "welcome" not in got, got
        health = probe.health()
        assert health["counters"]["impostor_messages"] >= 2
        assert health["nacked"]["wrong_identity"] >= 2
        assert health["modules"]["A"]["link"] == "up"
    finally:
        impostor.close()


def test_an_unknown_key_and_a_plaintext_client_are_refused_at_the_handshake(ship) -> None:
    probe, agent = ship
    unknown = Rogue(zmq.Context.instance(), probe.endpoint, "C", keys_dir=probe.keys, pair=random_pair())
    plain = None
    try:
        assert unknown.send(hello("C"), wait_s=2.0, skip=()) == []
        sources = probe.health()["refused_connections"]["sources"]
        assert any(s["reason"] == "unknown_key" and s["address"] == "127.0.0.1" for s in sources), sources
        before = probe.health()["refused_connections"]["total"]
        plain = Rogue(zmq.Context.instance(), probe.endpoint, "D")
        assert plain.send(hello("D"), wait_s=2.0, skip=()) == []
        health = probe.health()
        # The ship sees a plaintext client as one (mechanism mismatch), or as a handshake that
        # broke off, when the client noticed the mismatch and hung up first.
        assert health["refused_connections"]["total"] > before, health["refused_connections"]
        sources = health["refused_connections"]["sources"]
        assert {s["reason"] for s in sources} & {"plaintext", "no_handshake"}, sources
        assert "C" not in health["modules"] and "D" not in health["modules"]
        assert probe.rows("SELECT id FROM modules WHERE id IN ('C', 'D')") == []
        assert agent.refusal is None
    finally:
        unknown.close()
        if plain is not None:
            plain.close()


def test_200_hellos_from_unknown_keys_make_no_module_and_no_alarm(ship) -> None:
    probe, agent = ship
    before = probe.health()["refused_connections"]["total"]
    alarms = probe.rows("SELECT COUNT(*) FROM alarms")[0][0]
    events = probe.rows("SELECT COUNT(*) FROM events WHERE kind IN ('alarm', 'link')")[0][0]
    ctx = zmq.Context.instance()
    rogues = [
        Rogue(ctx, probe.endpoint, f"ghost{i}", keys_dir=probe.keys, pair=random_pair()) for i in range(200)
    ]
    try:
        for i, r in enumerate(rogues):
            # A rogue whose handshake was already refused has no pipe left to queue on (EAGAIN);
            # the refusal being counted is what matters, not whether its hello was queued.
            with contextlib.suppress(zmq.Again):
                r.sock.send_multipart(hello(f"ghost{i}"), zmq.NOBLOCK)
        assert wait_for(lambda: probe.health()["refused_connections"]["total"] - before >= 200, 30)
        assert all(r.collect(0.01, skip=()) == [] for r in rogues)
    finally:
        for r in rogues:
            r.close()
    time.sleep(2.0)  # a link alarm would come after its timeout
    health = probe.health()
    assert not [m for m in health["modules"] if m.startswith("ghost")]
    assert probe.rows("SELECT COUNT(*) FROM modules WHERE id LIKE 'ghost%'") == [(0,)]
    assert probe.rows("SELECT COUNT(*) FROM alarms")[0][0] == alarms
    assert probe.rows("SELECT COUNT(*) FROM events WHERE kind IN ('alarm', 'link')")[0][0] == events
    refused = health["refused_connections"]
    assert refused["last_minute"] >= 200 and len(refused["sources"]) <= 16  # counted, but bounded
    acked = agent.counters["acked"]
    assert wait_for(lambda: agent.counters["acked"] > acked, 20), "the flood stalled module A"
    assert probe.alive()


def test_a_key_added_while_the_ingest_runs_is_let_in(ship) -> None:
    probe, _ = ship
    late = probe.rogue("E")  # makes modules/E.key now, after the ingest started
    try:
        assert [m.type for m in late.send(hello("E"))] == ["welcome"]
    finally:
        late.close()


def test_keys_are_created_and_listed_by_the_cli(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from camcal.cli import app

    keys = tmp_path / "keys"
    res = CliRunner().invoke(app, ["keys", "create", "A", "B", "--keys", str(keys)])
    assert res.exit_code == 0, res.output
    listed = CliRunner().invoke(app, ["keys", "list", "--keys", str(keys)], terminal_width=200)
    assert listed.exit_code == 0, listed.output
    lines = {line.split()[0]: line for line in listed.output.splitlines()[1:]}
    assert set(lines) == {"ship", "A", "B"}
    pair = wire.ship_pair(keys)
    assert pair.public.decode() in lines["ship"] and "secret here" in lines["A"]
    assert (keys / "modules" / "A.key_secret").stat().st_mode & 0o077 == 0, "a secret readable by others"
    again = CliRunner().invoke(app, ["keys", "create", "--keys", str(keys)])
    assert again.exit_code == 0 and wire.ship_pair(keys) == pair, "create must keep existing keys"
    bad = CliRunner().invoke(app, ["keys", "create", "..", "--keys", str(keys)])
    assert bad.exit_code == 2 and "not a module id" in bad.output


def test_a_key_that_looks_like_markup_is_listed_as_it_is(tmp_path: Path) -> None:
    """Z85 keys hold "[" and "]": a key with "[b]" in it lost those three characters in `keys list`
    (rich read them as markup; with random keys the test above failed now and then)."""
    from typer.testing import CliRunner

    from camcal.cli import app

    keys = tmp_path / "keys"
    assert CliRunner().invoke(app, ["keys", "create", "A", "--keys", str(keys)]).exit_code == 0
    public = "0[b]0" + "0" * 35
    (keys / "modules" / "A.key").write_text(f'curve\n    public-key = "{public}"\n')
    listed = CliRunner().invoke(app, ["keys", "list", "--keys", str(keys)], terminal_width=200)
    assert listed.exit_code == 0, listed.output
    assert public in listed.output, listed.output
