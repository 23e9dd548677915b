"""Does this ship keep the protocol? A module's conformance kit (`camcal lrm conformance`).

It connects to a ship as the module whose key it is given, and walks the
numbered rules of ``docs/protocol.md`` that bind a ship
(`camcal.core.wire.rules`): the handshake with keys the ship does not know,
routing ids anyone could guess, every kind of malformed message, data before
``hello`` and beyond the window, acknowledgements and resends, a conflict,
heartbeats and ``bye``. Each answer is compared with what the document
promises, and the report gives pass or fail per rule number.

It stores a few small frames and one sensor batch under the module's id and
a boot of its own (``conformance-…``), raises the conflict alarm once and
signs the boot off at the end: run it against a ship recording a test dive.
"""

from __future__ import annotations

import contextlib
import json
import secrets
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Any

import cv2
import numpy as np
import zmq

from camcal.core import wire
from camcal.core.wire.rules import Report
from camcal.core.wire.sockets import new_route

#: Seconds a check waits for an answer that should come (generous: a busy ship is still a good ship).
ANSWER_S = 10.0
#: Seconds a check waits to be sure that no answer comes.
SILENCE_S = 2.0


@dataclass
class Reply:
    """A message from the ship: decoded, and its header's JSON as sent (to see which fields it left out)."""

    msg: Any
    raw: dict[str, Any]

    @property
    def type(self) -> str:
        return str(self.msg.type)


class Client:
    """A DEALER to the ship: sends raw frames, collects replies."""

    def __init__(
        self,
        ctx: zmq.Context[Any],
        endpoint: str,
        route: bytes,
        keys: wire.ModuleKeys | None,
        *,
        server_key: bytes | None = None,
    ) -> None:
        self.sock = ctx.socket(zmq.DEALER)
        if keys is not None:
            self.sock.setsockopt(zmq.CURVE_SERVERKEY, server_key or keys.ship_public)
            self.sock.setsockopt(zmq.CURVE_PUBLICKEY, keys.pair.public)
            self.sock.setsockopt(zmq.CURVE_SECRETKEY, keys.pair.secret)
        self.sock.setsockopt(zmq.ROUTING_ID, route)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(endpoint)
        self.bad_replies = 0

    def send(self, parts: list[bytes]) -> None:
        # Not connected (yet, or refused): the message is dropped, and the check sees silence.
        with contextlib.suppress(zmq.Again):
            self.sock.send_multipart(parts, zmq.NOBLOCK)

    def collect(
        self, wait_s: float, expect: int = 1, skip: tuple[str, ...] = ("ship_heartbeat",)
    ) -> list[Reply]:
        got: list[Reply] = []
        end = time.monotonic() + wait_s
        while len(got) < expect and time.monotonic() < end:
            if not self.sock.poll(20):
                continue
            parts = self.sock.recv_multipart()
            try:
                msg, _ = wire.decode(parts, allowed=wire.SHIP_TYPES)
                raw = json.loads(parts[0])
            except (wire.ProtocolError, ValueError):
                self.bad_replies += 1
                continue
            if msg.type not in skip:
                got.append(Reply(msg, raw))
        return got

    def ask(self, parts: list[bytes], wait_s: float = ANSWER_S, expect: int = 1) -> list[Reply]:
        self.send(parts)
        return self.collect(wait_s, expect)

    def close(self) -> None:
        self.sock.close(0)


def _header(fields: dict[str, Any], raw: dict[str, str] | None = None) -> bytes:
    """A header as JSON, ``raw`` fields written verbatim (``NaN``, ``1.0``: what json would not write)."""
    obj = dict(fields)
    for k in raw or {}:
        obj[k] = f"__RAW_{k}__"
    text = json.dumps(obj)
    for k, v in (raw or {}).items():
        text = text.replace(f'"__RAW_{k}__"', v)
    return text.encode()


class ShipConformance:
    """The checks of one ship (see the module docstring); `run` returns the report."""

    def __init__(
        self, endpoint: str, module: str, keys: wire.ModuleKeys | None, dive: str | None = None
    ) -> None:
        self.endpoint = endpoint
        self.module = module
        self.keys = keys
        self.dive = dive
        self.ctx: zmq.Context[Any] = zmq.Context.instance()
        self.report = Report("ship")
        self.boot = f"conformance-{secrets.token_hex(4)}"
        self.t0 = datetime.now(UTC).replace(microsecond=0)
        self.image = self._png(np.full((48, 64), 17, np.uint8))
        self.window = 8
        self.heartbeat_s = 1.0

    # -- messages ----------------------------------------------------------
    @staticmethod
    def _png(img: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".png", img)
        assert ok
        return bytes(buf.tobytes())

    def _base(self, kind: str, **fields: Any) -> dict[str, Any]:
        base = {"v": 1, "type": kind, "module": self.module, "boot": self.boot}
        if self.dive:
            base["dive"] = self.dive
        return {**base, **fields}

    def hello(self, **over: Any) -> list[bytes]:
        return [_header(self._base("hello", **over))]

    def frame(
        self, seq: int, image: bytes | None = None, raw: dict[str, str] | None = None, **over: Any
    ) -> list[bytes]:
        data = self.image if image is None else image
        fields = self._base(
            "frame",
            seq=seq,
            captured_at=self.t0.isoformat(),
            camera=self.module,
            wavelength_nm=460,
            exposure_s=0.05,
            gain_db=8.0,
            width_px=64,
            height_px=48,
            size=len(data),
            sha256=wire.sha256_hex(data),
        )
        return [_header({**fields, **over}, raw), data]

    def sensors(self, seq: int, rows: list[list[Any]], columns: tuple[str, ...]) -> list[bytes]:
        data = json.dumps(rows).encode()
        fields = self._base(
            "sensors",
            seq=seq,
            columns=list(columns),
            count=len(rows),
            size=len(data),
            sha256=wire.sha256_hex(data),
        )
        return [_header(fields), data]

    # -- checks --------------------------------------------------------------
    def _refused(self, number: int, replies: list[Reply], reason: str, what: str, **want: Any) -> bool:
        got = [(r.type, getattr(r.msg, "reason", None)) for r in replies]
        ok = got == [("nack", reason)]
        if ok:
            nack = replies[0].msg
            for field, value in want.items():
                ok = ok and getattr(nack, field) == value
        return self.report.check(number, ok, f"{what}: expected one nack {reason} {want or ''}, got {got}")

    def run(self) -> Report:
        main = Client(self.ctx, self.endpoint, new_route(self.module), self.keys)
        try:
            self._handshake()
            self._routes()
            self._session(main)
        finally:
            main.close()
        return self.report

    def _handshake(self) -> None:
        """Rule 1: an unknown key and a plaintext client get nothing."""
        if self.keys is None:
            self.report.skip(1, "the ship runs a plaintext link (a lab bench): no key to refuse")
            self.report.skip(3, "a plaintext link has no key to check the module against")
            return
        public, secret = zmq.curve_keypair()
        stranger = wire.ModuleKeys(self.module, wire.KeyPair(public, secret), self.keys.ship_public)
        for what, keys in (("an unknown key", stranger), ("a plaintext client", None)):
            c = Client(self.ctx, self.endpoint, new_route(self.module), keys)
            try:
                replies = c.ask(self.hello(boot=f"{self.boot}-x"), wait_s=SILENCE_S)
                self.report.check(1, replies == [], f"{what}: the ship answered {[r.type for r in replies]}")
            finally:
                c.close()

    def _routes(self) -> None:
        """Rule 2: guessable routing ids are refused; rule 3: a header naming another module."""
        for route in (self.module.encode(), f"{self.module}/1234".encode()):
            c = Client(self.ctx, self.endpoint, route, self.keys)
            try:
                self._refused(2, c.ask(self.hello()), "wrong_identity", f"routing id {route!r}")
            finally:
                c.close()
        if self.keys is not None:
            other = f"{self.module}-other"
            c = Client(self.ctx, self.endpoint, new_route(other), self.keys)
            try:
                parts = [_header({**self._base("hello"), "module": other})]
                self._refused(
                    3, c.ask(parts), "wrong_identity", f"header module {other!r}, key of {self.module!r}"
                )
            finally:
                c.close()

    def _session(self, c: Client) -> None:
        r = self.report
        # Rule 12: data before hello, then hello.
        self._refused(12, c.ask(self.frame(1)), "no_hello", "a frame before hello", retry=True)
        welcome = c.ask(self.hello())
        ok = [w.type for w in welcome] == ["welcome"]
        if ok:
            w = welcome[0].msg
            ok = w.window >= 1 and w.heartbeat_s > 0 and w.ingest is not None
            self.window, self.heartbeat_s = w.window, w.heartbeat_s
            self.dive = self.dive or w.dive
        r.check(12, ok, f"hello: expected a welcome with window, heartbeat_s and ingest, got {welcome}")
        if not ok:
            return
        # Rules 4-11: malformed messages, each its reason.
        big = _header(self._base("hello", software="x" * (64 * 1024)))
        cases: list[tuple[int, list[bytes], str, str]] = [
            (4, [*self.frame(2), b"third"], "bad_framing", "three frames"),
            (4, self.frame(2)[:1], "bad_framing", "a frame without its payload"),
            (4, [self.hello()[0], b"payload"], "bad_framing", "a hello with a payload"),
            (4, [big], "oversized", "a header over 64 KiB"),
            (5, self.frame(2, raw={"gain_db": "NaN"}), "bad_header", "gain NaN"),
            (5, [b'{"v":1,"v":1,"type":"hello"}'], "bad_header", "a key twice"),
            (5, [b"not json"], "bad_header", "not JSON"),
            (6, self.frame(2, raw={"v": "1.0"}), "bad_version", "v 1.0"),
            (6, self.frame(2, raw={"v": '"1"'}), "bad_version", 'v "1"'),
            (7, self.frame(2, raw={"seq": '"2"'}), "invalid_field", 'seq "2"'),
            (7, self.frame(2, boot="B\n"), "invalid_field", "a boot ending in a newline"),
            (7, self.frame(2, exposure_s=-1), "invalid_field", "a negative exposure"),
            (8, [_header(self._base("nonsense"))], "unknown_type", "type nonsense"),
            (8, [_header(self._base("welcome", window=1))], "unknown_type", "a ship's type"),
            (9, self.frame(2, sha256="0" * 64), "bad_payload", "a wrong sha256"),
            (10, self.frame(2, width_px=65), "bad_image", "an image of another width"),
            (
                11,
                self.sensors(2, [[None, 4.0]], ("t_unix_s", "temperature_c")),
                "invalid_field",
                "t_unix_s null",
            ),
            (
                11,
                self.sensors(2, [[1.8e9, 999.0]], ("t_unix_s", "humidity_pct")),
                "invalid_field",
                "humidity 999 %",
            ),
        ]
        for number, parts, reason, what in cases:
            replies = c.ask(parts)
            if self._refused(number, replies, reason, what):
                nack = replies[0]
                r.check(21, nack.msg.retry == wire.REASONS[reason].retry, f"{what}: retry {nack.msg.retry}")
                if reason in ("bad_header", "oversized"):  # nothing could be read: boot, seq and of left out
                    left_out = not {"boot", "seq", "of"} & set(nack.raw)
                    r.check(
                        21,
                        left_out,
                        f"{what}: the nack carries {sorted(set(nack.raw) & {'boot', 'seq', 'of'})}",
                    )
                if reason in ("bad_payload", "bad_image", "invalid_field") and number != 7:
                    r.check(
                        14,
                        (nack.msg.boot, nack.msg.seq) == (self.boot, 2),
                        f"{what}: nack names {nack.msg.boot}/{nack.msg.seq}",
                    )
        # Rules 14-16: stored once, acknowledged in inclusive ranges, resends and conflicts.
        self._acked(c, self.frame(1), 1, "a frame")
        self._acked(
            c, self.frame(1, sent_at=datetime.now(UTC).isoformat()), 1, "the same frame sent again", rule=15
        )
        self._acked(c, self.sensors(2, [[1.8e9, 4.0]], ("t_unix_s", "temperature_c")), 2, "a sensor batch")
        for what, change in (
            ("another wavelength", {"wavelength_nm": 520}),
            ("another capture time", {"captured_at": "2026-01-01T00:00:00Z"}),
        ):
            self._refused(
                16, c.ask(self.frame(1, **change)), "conflict", f"seq 1 again with {what}", retry=False, seq=1
            )
        image = self._png(np.full((48, 64), 99, np.uint8))
        self._refused(16, c.ask(self.frame(1, image=image)), "conflict", "seq 1 again with another image")
        # Rule 13: a burst beyond the window; rule 14: each message one answer.
        first, n = 10, self.window + 4
        for q in range(first, first + n):
            c.send(self.frame(q, image=self._png(np.full((48, 64), q % 250, np.uint8))))
        settled: dict[int, list[str]] = {}
        end = time.monotonic() + ANSWER_S + n
        while len(settled) < n and time.monotonic() < end:  # (one ack may answer several)
            for reply in c.collect(0.5, expect=n):
                m = reply.msg
                if m.type == "ack":
                    for _, a, z in m.ranges:
                        for q in range(a, z + 1):
                            settled.setdefault(q, []).append("ack")
                elif m.type == "nack":
                    settled.setdefault(m.seq, []).append(m.reason)
        for reply in c.collect(0.5, expect=n):  # (nothing more may come: one answer each)
            for q in [q for _, a, z in getattr(reply.msg, "ranges", ()) for q in range(a, z + 1)]:
                settled.setdefault(q, []).append("ack")
            if reply.type == "nack":
                settled.setdefault(reply.msg.seq, []).append(reply.msg.reason)
        one_each = sorted(settled) == list(range(first, first + n)) and all(
            len(v) == 1 for v in settled.values()
        )
        r.check(14, one_each, f"a burst of {n}: answers per seq {settled}")
        over = sum(v == ["over_window"] for v in settled.values())
        r.check(
            13, over >= 1, f"{n} frames at once with a window of {self.window}: {over} refused over_window"
        )
        r.check(18, one_each, "the burst's answers could not all be matched by boot and seq")
        # Rule 19: the ship's heartbeat; rule 20: what gets no answer.
        beats = c.collect(
            2 * self.heartbeat_s + SILENCE_S, expect=1, skip=("ack", "nack", "welcome", "command")
        )
        r.check(19, bool(beats), f"no ship_heartbeat within {2 * self.heartbeat_s + SILENCE_S:g} s")
        r.skip(19, "the 5 s link timeout is not waited for")
        quiet = c.ask([_header(self._base("heartbeat"))], wait_s=SILENCE_S)
        r.check(
            20,
            [q.type for q in quiet if q.type != "welcome"] == [],
            f"a heartbeat was answered {[q.type for q in quiet]}",
        )
        replies = c.ask([_header(self._base("bye", boot=f"{self.boot}-old"))])
        self._refused(20, replies, "invalid_field", "a bye of another boot")
        r.check(
            20,
            c.ask([_header(self._base("bye"))], wait_s=SILENCE_S) == [],
            "the bye of the module's boot was answered",
        )
        r.skip(22, "checking busy needs a flood of data (tests/live/test_fairness.py does it)")

    def _acked(self, c: Client, parts: list[bytes], seq: int, what: str, rule: int = 14) -> None:
        replies = c.ask(parts)
        acks = [x.msg for x in replies if x.type == "ack"]
        ok = (
            len(replies) == 1
            and bool(acks)
            and any(b == self.boot and a <= seq <= z for b, a, z in acks[0].ranges)
        )
        self.report.check(
            rule, ok, f"{what}: expected an ack holding {self.boot}/{seq}, got {[x.raw for x in replies]}"
        )
        if ok:
            inclusive = any((b, a, z) == (self.boot, seq, seq) for b, a, z in acks[0].ranges)
            self.report.check(
                14, inclusive, f"{what}: a lone message's range is not [{seq}, {seq}]: {acks[0].ranges}"
            )
