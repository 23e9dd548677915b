"""Why the ship refuses a message: the reasons a ``nack`` carries, and whether resending can help.

One list for the ship, the reference module and ``docs/protocol.md``
(a test checks the document names each of them).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Reason:
    name: str
    retry: bool  # can sending the same message again succeed?
    meaning: str
    #: The ship's own state, not the message: resend for as long as it takes (a full disk, a
    #: database being restarted), not a limited number of times like a damaged copy.
    until_it_works: bool = False


_ALL = (
    Reason(
        "bad_framing", False, "not 1 or 2 frames, or a payload where none belongs (or none where one must be)"
    ),
    Reason("oversized", False, "header over 64 KiB or payload over the ship's limit"),
    Reason("bad_header", False, "header is not UTF-8 JSON of the protocol's dialect, or not an object"),
    Reason("bad_version", False, "protocol version other than 1"),
    Reason("unknown_type", False, "message type unknown, or one the ship does not accept"),
    Reason("invalid_field", False, "a header field (or a sensor value) missing, mistyped, out of range"),
    Reason(
        "bad_payload",
        True,
        "payload does not match the header's size or sha256: damaged on the way, or on the SD card "
        "(resend from the card a few times, then give up and keep it for `camcal import`)",
    ),
    Reason("bad_image", False, "frame payload is not an 8-bit grayscale PNG/TIFF of the stated size"),
    Reason(
        "wrong_identity",
        False,
        "the header's module differs from the module the connection's key belongs to (or, on a "
        "plaintext link, from its routing id)",
    ),
    Reason(
        "wrong_dive",
        True,
        "this ingest records another dive than the one the message names: keep everything in the "
        "outbox and look for the ingest of that dive",
    ),
    Reason(
        "not_served",
        True,
        "this ingest does not serve the module (several ingests share a ship): keep everything in "
        "the outbox and look for the right one",
        until_it_works=True,
    ),
    Reason(
        "no_hello",
        True,
        "a data message from a module the ship has not welcomed since its link came up (or since the "
        "ship started): say hello, wait for welcome, then resend",
        until_it_works=True,
    ),
    Reason(
        "over_window",
        True,
        "more data messages of the module unanswered than the window allows: wait for answers, then "
        "resend it",
        until_it_works=True,
    ),
    Reason(
        "busy",
        True,
        "the ship holds too much of this module's data not yet stored (a flood): resend it once "
        "earlier messages are acknowledged, after a pause; nothing is wrong with the message",
        until_it_works=True,
    ),
    Reason(
        "conflict",
        False,
        "this (module, boot, seq) is stored with other content; the ship keeps the first and raises an alarm",
    ),
    Reason(
        "internal_error",
        True,
        "the ship failed to store it (its disk or database, not the message): resend later, for as "
        "long as it takes",
        until_it_works=True,
    ),
    Reason(
        "quarantined",
        False,
        "storing it failed twice while other messages were stored: kept aside on the ship for inspection",
    ),
)

REASONS: dict[str, Reason] = {r.name: r for r in _ALL}
#: Reasons of messages refused while decoding (counted as malformed).
DECODE_REASONS = frozenset(
    {
        "bad_framing",
        "oversized",
        "bad_header",
        "bad_version",
        "unknown_type",
        "invalid_field",
        "bad_payload",
        "bad_image",
    }
)


def retry(reason: str) -> bool:
    return REASONS[reason].retry
