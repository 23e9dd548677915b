"""Does this module keep the protocol? The ship's conformance kit (`camcal ingest --conformance`).

A ship that stores nothing: it listens where an ingest would (CURVE with
the ship's keys, or plaintext), lets one module connect, and walks the
numbered rules of ``docs/protocol.md`` that bind a module
(`camcal.core.wire.rules`). It watches every message the module sends
(routing id, the dialect and fields, ``hello`` first, the window, a resend
that keeps its content, heartbeats) and provokes what a module must handle,
one step after the other as the module's data comes in:

1. a few messages acknowledged as they come;
2. a message left unanswered, then a new ``welcome`` (a restarted ship): the
   module must send it again, unchanged;
3. a ``nack`` with retry (``internal_error``): the module must send it again,
   later;
4. a ``nack`` without retry (``quarantined``): the module must not send it again;
5. a ``nack`` ``not_served``: the module must send no data until its next
   ``welcome`` (it says ``hello`` again);
6. a command, twice under one id: the module must answer both with
   ``command_status`` and apply it once.

The window it gives is 2, so that a module that ignores it shows it soon.
It stops when every step is done (or after ``duration_s``) and returns the
report: pass or fail per rule number.
"""

from __future__ import annotations

import logging
import secrets
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import zmq

from camcal.core import wire
from camcal.core.wire.rules import Report
from camcal.core.wire.sockets import route_is_safe, route_module

log = logging.getLogger("camcal.ingest")

#: The window the conformance ship gives (small: a module that exceeds it shows it soon).
WINDOW = 2
HEARTBEAT_S = 1.0
#: Data that may still arrive after a ``not_served`` nack (sent before the module read it).
IN_FLIGHT_GRACE_S = 0.5
#: The rule a refusal of a module's message breaks.
RULE_OF_REASON = {
    "bad_framing": 4,
    "oversized": 4,
    "bad_header": 5,
    "bad_version": 6,
    "invalid_field": 7,
    "unknown_type": 4,
    "bad_payload": 9,
    "bad_image": 10,
}
STEPS = ("acknowledged", "resent after welcome", "resent after retry", "not resent", "not served", "command")


@dataclass
class Step:
    """One provocation and what the module did about it."""

    name: str
    key: tuple[str, int] | None = None  # the data message it concerns
    since: float = 0.0
    done: bool = False
    notes: list[str] = field(default_factory=list)


class ModuleConformance:
    """The conformance ship (see the module docstring); `run` returns the report."""

    def __init__(self, router: Any, poll: list[Any], handle_gate: Any, dive: str | None, duration_s: float):
        self.router = router
        self.poll_also = poll  # the ZAP handler's sockets (answered by ``handle_gate``)
        self.handle_gate = handle_gate
        self.dive = dive
        self.duration_s = duration_s
        self.report = Report("module")
        self.instance = secrets.token_hex(8)
        self.identity = b""
        self.module = ""
        self.welcomed_at: float | None = None
        self.contents: dict[tuple[str, int], str] = {}  # (boot, seq) -> content checksum
        self.unanswered: OrderedDict[tuple[str, int], float] = OrderedDict()
        self.acked: set[tuple[str, int]] = set()
        self.refused_for_good: set[tuple[str, int]] = set()
        self.last_beat: float | None = None  # the module's last heartbeat
        self.beat_sent = 0.0  # the ship's last heartbeat
        self.step = 0
        self.steps = [Step(n) for n in STEPS]
        self.acked_count = 0
        self.command_id = f"conformance-{secrets.token_hex(4)}"
        self.statuses: list[str] = []
        self.not_served_at: float | None = None

    # -- the loop --------------------------------------------------------------
    def run(self) -> Report:
        poller = zmq.Poller()
        for sock in [self.router, *self.poll_also]:
            poller.register(sock, zmq.POLLIN)
        end = time.monotonic() + self.duration_s
        while time.monotonic() < end and self.step < len(self.steps):
            events = dict(poller.poll(50))
            if any(s in events for s in self.poll_also):
                self.handle_gate()
            if self.router in events:
                for _ in range(64):
                    try:
                        parts = self.router.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self._message(parts[0].bytes, [p.bytes for p in parts[1:]])
            self._tick()
        self._finish()
        return self.report

    def _send(self, msg: Any) -> None:
        if self.identity:
            self.router.send_multipart([self.identity, *wire.encode(msg)])

    def _welcome(self) -> None:
        self.instance = secrets.token_hex(8)
        self._send(
            wire.Welcome(
                module="ship", window=WINDOW, heartbeat_s=HEARTBEAT_S, ingest=self.instance, dive=self.dive
            )
        )
        self.welcomed_at = time.monotonic()

    def _nack(self, reason: str, detail: str, msg: Any | None = None) -> None:
        ref = wire.message_ref(msg) if msg is not None else {}
        self._send(
            wire.Nack(
                module="ship",
                boot=ref.get("boot"),
                seq=ref.get("seq"),
                of=ref.get("type"),
                reason=reason,
                retry=wire.REASONS[reason].retry,
                detail=detail,
            )
        )
        if msg is not None and ref.get("seq") is not None:
            self.unanswered.pop((msg.boot, msg.seq), None)

    def _ack(self, key: tuple[str, int]) -> None:
        self._send(wire.Ack(module="ship", ranges=((key[0], key[1], key[1]),), window=WINDOW))
        self.unanswered.pop(key, None)
        self.acked.add(key)

    # -- one message -------------------------------------------------------------
    def _message(self, identity: bytes, frames: list[bytes]) -> None:
        r = self.report
        now = time.monotonic()
        try:
            msg, _ = wire.decode(frames, allowed=wire.MODULE_TYPES)
        except wire.ProtocolError as exc:
            rule = RULE_OF_REASON.get(exc.kind, 4)
            if exc.kind == "invalid_field" and exc.ref.get("type") == "sensors" and "payload" in exc.detail:
                rule = 11
            r.check(rule, False, f"a message refused {exc.kind}: {exc.detail[:200]}")
            self.identity = self.identity or identity
            self._nack(exc.kind, exc.detail[:500])
            return
        if not self.module:
            self.module = msg.module
            log.info("conformance: module %s connected", self.module)
        if msg.module != self.module:
            return  # another module: one at a time
        r.check(
            2,
            route_is_safe(identity) and route_module(identity) == msg.module,
            f"routing id {identity[:80]!r}",
        )
        self.identity = identity
        kind = msg.type
        if kind == "hello":
            self.dive = self.dive or msg.dive or "conformance"
            if self.not_served_at is not None:  # it went back to saying hello, as it must
                self.report.check(24, True)
                self.not_served_at = None
                self._advance("not served")
            self._welcome()
        elif kind == "heartbeat":
            if self.last_beat is not None and self.welcomed_at is not None:
                gap = now - self.last_beat
                r.check(19, gap <= 2 * HEARTBEAT_S + 1.0, f"{gap:.1f} s between two heartbeats")
            self.last_beat = now
            if self.welcomed_at is None:  # (a ship that restarted under a module welcomes it again)
                self._welcome()
        elif kind == "command_status":
            if msg.command_id == self.command_id:
                self.statuses.append(msg.state)
        elif kind in ("frame", "sensors"):
            self._data(msg, now)

    def _data(self, msg: Any, now: float) -> None:
        r = self.report
        key = (msg.boot, msg.seq)
        content = wire.content_sha256(msg)
        first = self.contents.setdefault(key, content)
        r.check(16, first == content, f"{msg.boot}/{msg.seq} sent again with other content")
        if self.not_served_at is not None:
            if now - self.not_served_at > IN_FLIGHT_GRACE_S:
                r.check(24, False, f"data ({msg.boot}/{msg.seq}) after not_served, before a new welcome")
            self._nack("not_served", "this conformance ship serves no data now", msg)
            return
        if self.welcomed_at is None:
            r.check(12, False, f"data ({msg.boot}/{msg.seq}) before a welcome")
            r.check(24, False, "data before a welcome")
            self._nack("no_hello", "say hello first", msg)
            return
        if key in self.refused_for_good:
            r.check(17, False, f"{msg.boot}/{msg.seq} sent again after a nack without retry")
            self._nack("quarantined", "refused for good before", msg)
            return
        if key not in self.unanswered and len(self.unanswered) >= WINDOW:
            r.check(13, False, f"{len(self.unanswered) + 1} data messages unanswered, window {WINDOW}")
        self.unanswered.setdefault(key, now)
        self._provoke(msg, key, now)

    # -- the steps ------------------------------------------------------------------
    def _advance(self, name: str) -> None:
        if self.step < len(self.steps) and self.steps[self.step].name == name:
            self.steps[self.step].done = True
            self.step += 1

    def _provoke(self, msg: Any, key: tuple[str, int], now: float) -> None:
        step = self.steps[self.step] if self.step < len(self.steps) else None
        name = step.name if step else ""
        if name == "acknowledged" or step is None:
            self._ack(key)
            self.acked_count += 1
            if self.acked_count >= 3:
                self._advance("acknowledged")
        elif name == "resent after welcome":
            if step.key is None:  # leave it unanswered, and welcome again in a moment (`_tick`)
                step.key, step.since = key, now
            elif key == step.key and self.welcomed_at is not None and self.welcomed_at > step.since:
                self.report.check(17, True)
                self._ack(key)
                self._advance(name)
            else:
                self._ack(key)
        elif name == "resent after retry":
            if step.key is None:
                step.key, step.since = key, now
                self._nack("internal_error", "conformance: resend it later", msg)
            elif key == step.key:
                self.report.check(17, True)
                self._ack(key)
                self._advance(name)
            else:
                self._ack(key)
        elif name == "not resent":
            self.refused_for_good.add(key)
            step.key, step.since = key, now
            self._nack("quarantined", "conformance: refused for good, do not send it again", msg)
            self._advance(name)
        elif name == "not served":
            self.not_served_at = now
            self.welcomed_at = None
            self._nack("not_served", "conformance: this ship does not serve the module now", msg)
        else:
            self._ack(key)

    def _tick(self) -> None:
        now = time.monotonic()
        if self.identity and self.welcomed_at is not None and now - self.beat_sent >= HEARTBEAT_S:
            self.beat_sent = now
            self._send(wire.ShipHeartbeat(module="ship", window=WINDOW))
        if self.step >= len(self.steps):
            return
        step = self.steps[self.step]
        welcomed = self.welcomed_at
        waited = step.key is not None and now - step.since > 0.5
        if step.name == "resent after welcome" and waited and welcomed is not None and welcomed < step.since:
            self._welcome()  # a ship that restarted: what is unanswered must come again
        if step.name == "command":
            if step.since == 0.0:
                step.since = now
                self._command()
            elif len(self.statuses) == 1 and len(step.notes) == 0:
                step.notes.append("repeated")
                self._command()  # the same id again: answered again, applied once
            elif len(self.statuses) >= 2:
                same = self.statuses[1] == self.statuses[0] or self.statuses[1] == "done"
                self.report.check(23, same, f"a repeated command got {self.statuses}")
                self._advance("command")

    def _command(self) -> None:
        self._send(
            wire.Command(module="ship", command_id=self.command_id, action="resume", issued_by="conformance")
        )

    def _finish(self) -> None:
        r = self.report
        if self.module == "":
            for rule in r.verdicts:
                r.skip(rule, f"no module connected within {self.duration_s:g} s")
            return
        for rule in (4, 5, 6, 7, 9, 10, 11, 12, 16):
            r.check(rule, True)  # what it sent kept these rules (a failure above stays a failure)
        if self.welcomed_at is not None or self.steps[0].done:
            r.check(13, True)
            r.check(18, True)
        if self.last_beat is not None:
            r.check(19, True)
        rule_of_step = {
            "acknowledged": 12,
            "resent after welcome": 17,
            "resent after retry": 17,
            "not resent": 17,
            "not served": 24,
            "command": 23,
        }
        for step in self.steps[self.step :]:
            late = f"step '{step.name}': the module did not get there within {self.duration_s:g} s"
            r.check(rule_of_step[step.name], False, late)
        if self.steps[3].done:  # a message refused for good was not sent again since (checked as it came)
            r.check(17, True)
