"""The module's check of its peer, against a real TCP peer whose handshake fails in changing ways."""

from __future__ import annotations

import time
from pathlib import Path

import zmq

from camcal.core.wire import module_keys
from camcal.core.wire.keys import create_module_key, create_ship_key
from lrm.shipcheck import ShipCheck
from tests.utils.peers import HTTP_ERROR, NULL_GREETING, tcp_peer


def test_a_refusal_counts_from_the_first_failure_whatever_reasons_follow(tmp_path: Path) -> None:
    """A simulated module gives a refusing peer a grace before it gives up. Two defects kept one
    trying a port that answers HTTP for over a minute under load (twice in CI): a new reason (a
    mechanism mismatch, then a dropped greeting) restarted the grace, and a monitor attached after
    the connect could miss CONNECTED, so a peer that hung up looked like no failure and no new
    socket was ever made. The refusal's start stays the first failure's; every failure renews."""
    create_ship_key(tmp_path)
    create_module_key(tmp_path, "A")
    ctx = zmq.Context()
    # One connection greeted as a plaintext ZeroMQ peer, the next with HTTP, and so on (each held
    # long enough for the module to read it).
    with tcp_peer(lambda n: NULL_GREETING if n % 2 else HTTP_ERROR, hold_s=0.2) as endpoint:
        check = ShipCheck("A", endpoint, None, module_keys(tmp_path, "A"))
        sock = check.open(ctx)
        reasons: list[str] = []
        starts: set[float] = set()
        sockets, deadline = 1, time.monotonic() + 40
        try:
            while sockets < 6 and time.monotonic() < deadline:
                check.watch()
                if check.refusal is not None:
                    starts.add(check.refusal.since_mono)
                    if not reasons or reasons[-1] != check.refusal.reason:
                        reasons.append(check.refusal.reason)
                if check.renew_due():  # as the agent does: a new socket after a failed handshake
                    check.close(sock)
                    sock = check.open(ctx)
                    sockets += 1
                time.sleep(0.02)
        finally:
            check.close(sock)
            ctx.term()
    assert sockets == 6, "the module did not try the peer again"
    assert len(starts) == 1, f"the refusal restarted {len(starts) - 1} times; reasons seen: {reasons}"
    # Each failure said once, as it is: the disconnect after a refused mechanism is not another one.
    assert reasons[:4] == ["plaintext", "no_handshake", "plaintext", "no_handshake"], reasons
