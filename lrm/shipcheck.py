"""Is the peer on the other end the right ship? The module's side of the link's identity checks.

A module connects to whatever listens at ``--connect``. Before it sends a
single frame it wants to know three things, and `ShipCheck` answers them:

* **Does it speak the protocol?** The socket's monitor reports each
  handshake (ZMTP greeting, then CURVE). A peer that is not ZeroMQ, or is a
  ZeroMQ peer without the ship's key, or refuses this module's key, fails
  it; the check says which, in words a person can act on. libzmq stops
  retrying after some of these failures, so the check also tells the agent
  to make a new socket after a pause.
* **Is it a camcal ship?** A peer that handshakes but answers with messages
  that are not the protocol is refused too.
* **Does it record this module's dive?** ``welcome`` names the ingest and
  its dive; a module started for a dive (``--dive``) refuses an ingest of
  another dive (and a ship that does not say), as it does a ``nack``
  ``wrong_dive``. Nothing is sent to a refused ship but ``hello``; frames
  stay in the outbox.

`refusal` holds the current reason (None while the ship is right); a
refusal the ship itself made (another dive) is ``definitive``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any

import zmq
from zmq.utils.monitor import parse_monitor_message

from camcal.core import wire

log = logging.getLogger("camcal.lrm")

#: Seconds between new sockets after a handshake failure libzmq may not retry by itself.
RETRY_SOCKET_S = 3.0
#: Undecodable messages from a peer that never welcomed us, before it counts as not a camcal ship.
MAX_FOREIGN_MESSAGES = 3

_EVENTS = (
    zmq.EVENT_CONNECTED
    | zmq.EVENT_DISCONNECTED
    | zmq.EVENT_HANDSHAKE_SUCCEEDED
    | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL
    | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL
    | zmq.EVENT_HANDSHAKE_FAILED_AUTH
)
_MISMATCH = getattr(zmq, "PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH", 0x11000002)


@dataclass(frozen=True)
class Refusal:
    reason: str  # "wrong_dive", "not_camcal", "key_refused", "plaintext", "no_handshake"
    message: str
    since_mono: float
    definitive: bool = False


class ShipCheck:
    """The module's checks of the peer at ``connect`` (see the module docstring)."""

    def __init__(self, module: str, connect: str, dive: str | None, keys: wire.ModuleKeys | None) -> None:
        self.module, self.connect, self.dive, self.keys = module, connect, dive, keys
        self.refusal: Refusal | None = None
        #: The ingest and dive of the last welcome this module accepted.
        self.ship: dict[str, str | None] | None = None
        self.monitor: Any = None
        self._connected = False
        self._foreign = 0
        self.renew_at: float | None = None
        #: Handshakes that succeeded (ZMTP and, with keys, CURVE: the peer has the ship's key).
        self.handshakes = 0

    # -- the socket ------------------------------------------------------
    def open(self, ctx: zmq.Context[Any]) -> Any:
        """A new DEALER to the ship (CURVE with keys), watched by this check."""

        def watch_from_the_start(sock: Any) -> None:
            # Before the connect: a CONNECTED missed here made a peer that then hung up without a
            # handshake look like no failure at all, and nothing made a new socket (the module hung).
            self.monitor = sock.get_monitor_socket(_EVENTS)

        sock = wire.module_socket(
            ctx, self.connect, self.module, keys=self.keys, before_connect=watch_from_the_start
        )
        self._connected = False
        self.renew_at = None
        return sock

    def close(self, sock: Any) -> None:
        if self.monitor is not None:
            sock.disable_monitor()
            self.monitor.close(0)
            self.monitor = None
        sock.close(0)

    def watch(self) -> None:
        """Read the socket's handshake events (never blocks)."""
        while self.monitor is not None:
            try:
                event = parse_monitor_message(self.monitor.recv_multipart(zmq.NOBLOCK))
            except zmq.Again:
                return
            kind, value = event["event"], event["value"]
            if kind == zmq.EVENT_CONNECTED:
                self._connected = True
            elif kind == zmq.EVENT_HANDSHAKE_SUCCEEDED:
                self._connected = False
                self.handshakes += 1
                if self.refusal is not None and not self.refusal.definitive:
                    log.info("module %s: handshake with %s succeeded", self.module, self.connect)
                    self.refusal = None
            elif kind == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
                self._connected = False  # the disconnect that follows is this failure, not another
                self._refuse(
                    "key_refused",
                    f"the ship at {self.connect} refused this module's key (ZAP status {value}): "
                    f"on the ship, run `camcal keys create {self.module}` (or add this module's "
                    "public key to its keys/modules folder)",
                )
            elif kind == zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL and value == _MISMATCH:
                self._connected = False
                self._refuse(
                    "plaintext",
                    f"the peer at {self.connect} does not use the same link security as this module: "
                    + (
                        "it is not a CURVE server (a plaintext lab-bench ingest, or not a camcal ship)"
                        if self.keys is not None
                        else "it wants CURVE keys; give this module its keys (--keys)"
                    ),
                )
            elif kind in (zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL, zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL) or (
                kind == zmq.EVENT_DISCONNECTED and self._connected
            ):
                self._connected = False
                self._refuse(
                    "no_handshake",
                    f"the peer at {self.connect} does not complete the camcal link's handshake: it "
                    "is not a camcal ingest, or its ship key is not the one in "
                    + (f"{self.keys.module}'s keys folder (ship.key)" if self.keys else "use")
                    + "; check --connect",
                )

    def _refuse(self, reason: str, message: str, *, definitive: bool = False) -> None:
        now = time.monotonic()
        if self.refusal is None or self.refusal.reason != reason:
            log.error("module %s refuses the ship: %s", self.module, message)
            # Refused since the first failure, whatever the reasons that follow: a peer whose
            # failures alternate (a mechanism mismatch, then a dropped connection) must not restart
            # the grace a simulated module gives it (it once kept one waiting > 60 s under load).
            since = now if self.refusal is None else self.refusal.since_mono
            self.refusal = Refusal(reason, message, since, definitive)
        if reason != "wrong_dive" and self.renew_at is None:
            self.renew_at = now + RETRY_SOCKET_S  # libzmq may not try again by itself

    def renew_due(self) -> bool:
        return self.renew_at is not None and time.monotonic() >= self.renew_at

    # -- what the ship says ----------------------------------------------
    def accept_welcome(self, msg: wire.Welcome) -> bool:
        """Whether to stream to the ship that sent ``msg``; refuses an ingest of another dive."""
        self._foreign = 0
        if self.dive is not None and msg.dive != self.dive:
            self._refuse(
                "wrong_dive",
                f"the ingest at {self.connect} (instance {msg.ingest or 'unknown'}) records "
                + (f"dive {msg.dive!r}" if msg.dive else "a dive it does not name")
                + f", this module was started for dive {self.dive!r}: not sending it anything; frames "
                "stay in the outbox. Point --connect at the ingest of that dive, or start the module "
                "for the ingest's dive",
                definitive=True,
            )
            return False
        if self.ship != {"ingest": msg.ingest, "dive": msg.dive}:
            log.info(
                "module %s: welcomed by ingest %s, dive %s", self.module, msg.ingest or "?", msg.dive or "?"
            )
        self.ship = {"ingest": msg.ingest, "dive": msg.dive}
        self.refusal = None
        return True

    def wrong_dive(self, msg: wire.Nack) -> None:
        """The ship refused this module's dive (``nack`` ``wrong_dive``)."""
        self._refuse(
            "wrong_dive",
            f"the ingest at {self.connect} refused this module: {msg.detail or 'it records another dive'}",
            definitive=True,
        )

    def foreign_message(self, welcomed: bool) -> None:
        """A message from the peer that is not the protocol."""
        self._foreign += 1
        if not welcomed and self._foreign >= MAX_FOREIGN_MESSAGES:
            self._refuse(
                "not_camcal",
                f"the peer at {self.connect} speaks ZeroMQ but not the camcal protocol; check --connect",
            )
