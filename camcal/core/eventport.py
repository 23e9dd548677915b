"""The events port: the ingest's publisher and its subscribers, plaintext on loopback, CURVE beyond it.

The ingest publishes every event (frames, results, alarms, health, commands)
on a ZeroMQ PUB socket; the dashboard server, ``camcal doctor`` and ``camcal
up`` subscribe. On loopback (``tcp://127.0.0.1:5556``, the default, and
``ipc://``) only processes of the ship's computer can reach it, and it stays
plaintext. Bound beyond loopback (``tcp://*:5556`` for a dashboard in another
container or on another computer, several ingests), anyone on the ship's
network could subscribe and read every event, so it speaks CURVE there: the
ingest is the CURVE server with the ship's key pair, and a subscriber must
prove it holds the ship's secret key too (its ZAP handler, `ingest.events`,
lets that key in and no other: not a module's key, although every module
knows the ship's public key). A subscriber without it connects and receives
nothing. A ship without keys (``link_plaintext``) cannot publish beyond
loopback: the ingest refuses to start and says so.

Both sides decide from their own endpoint: CURVE when its host is not a
loopback address, unless ``events_curve`` says otherwise (``true``: CURVE
whatever the address, for a subscriber that reaches an ingest bound to
``tcp://*:5556`` through ``127.0.0.1``; ``false`` is refused beyond
loopback).
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import zmq

from camcal.core.wire.keys import KeyFileError, KeyPair, ship_pair

#: The ZAP domain of the events port (the module link's is ``camcal``).
EVENTS_ZAP_DOMAIN = b"camcal-events"
#: A CURVE handshake with the events port must end within this many milliseconds.
HANDSHAKE_MS = 5000


class EventPortError(ValueError):
    """An events port that cannot be opened as configured, with what to do about it."""


def on_loopback(endpoint: str) -> bool:
    """Whether only this computer can reach ``endpoint`` (``ipc://``, ``inproc://``, a loopback host)."""
    scheme, _, rest = endpoint.partition("://")
    if scheme in ("ipc", "inproc"):
        return True
    host = urlsplit(f"//{rest}").hostname or ""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # '*', a host name, an interface name: beyond loopback
        return False


def use_curve(endpoint: str, setting: bool | None = None) -> bool:
    """Whether the events port at ``endpoint`` speaks CURVE (see the module docstring)."""
    if setting is None:
        return not on_loopback(endpoint)
    if not setting and not on_loopback(endpoint):
        raise EventPortError(
            f"the events port {endpoint} is beyond loopback: it must be CURVE-encrypted "
            "(unset events_curve, or bind it to tcp://127.0.0.1:PORT)"
        )
    return setting


def port_keys(endpoint: str, keys_dir: Path | None) -> KeyPair:
    """The ship's key pair for a CURVE events port, or `EventPortError` saying what to do."""
    fix = (
        f"the events port {endpoint} is beyond loopback and needs the ship's key pair to encrypt it: "
        "run `camcal keys create` on the ship (the dashboard and `camcal doctor` need the same keys "
        "folder, CAMCAL_KEYS_DIR), or bind it to tcp://127.0.0.1:PORT"
    )
    if keys_dir is None:
        raise EventPortError(fix)
    try:
        return ship_pair(keys_dir)
    except KeyFileError as exc:
        raise EventPortError(f"{fix} ({exc})") from None


def subscriber(
    ctx: zmq.Context[Any],
    endpoint: str,
    *,
    keys_dir: Path | None,
    curve: bool | None = None,
    topics: Iterable[bytes] = (b"",),
    rcvhwm: int = 1000,
) -> Any:
    """A SUB socket connected to the events port at ``endpoint``; a CURVE client with the ship's key
    pair when the port speaks CURVE (`use_curve`)."""
    keys = port_keys(endpoint, keys_dir) if use_curve(endpoint, curve) else None
    sub = ctx.socket(zmq.SUB)
    if keys is not None:
        sub.setsockopt(zmq.CURVE_SERVERKEY, keys.public)
        sub.setsockopt(zmq.CURVE_PUBLICKEY, keys.public)
        sub.setsockopt(zmq.CURVE_SECRETKEY, keys.secret)
        sub.setsockopt(zmq.HANDSHAKE_IVL, HANDSHAKE_MS)
    for topic in topics:
        sub.setsockopt(zmq.SUBSCRIBE, topic)
    sub.setsockopt(zmq.RCVHWM, rcvhwm)
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(endpoint)
    return sub
