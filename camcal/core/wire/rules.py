"""The numbered rules of the protocol (``docs/protocol.md``, "The rules"), and a conformance report.

One list for the document and both conformance kits: `camcal lrm conformance`
(a module's view: does this ship keep the rules?) and `camcal ingest
--conformance` (the ship's view: does this module?). Each rule binds the
ship, the module or both; a kit checks the rules of the other side and
prints one line per rule number: pass, fail (with what it saw), or not
checked (with why).
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Rule:
    number: int
    binds: str  # "ship", "module" or "both"
    title: str


RULES: tuple[Rule, ...] = (
    Rule(
        1,
        "ship",
        "a client that has not the ship's key, or whose key the ship does not know, or that "
        "speaks no CURVE, is refused before any message passes",
    ),
    Rule(
        2,
        "both",
        "a module's routing id is its module id, '/' and 32 to 128 random hex digits, new at "
        "every start; the ship refuses any other (wrong_identity)",
    ),
    Rule(
        3,
        "ship",
        "a message whose module is not the module of the connection's key is refused (wrong_identity)",
    ),
    Rule(
        4,
        "both",
        "a message is one or two frames: a UTF-8 JSON header of at most 64 KiB, then a payload "
        "exactly for frame and sensors (bad_framing, oversized)",
    ),
    Rule(
        5,
        "both",
        "headers are JSON of the dialect: finite numbers of at most 40 characters, 64-bit "
        "integers, no key twice, at most 8 deep (bad_header)",
    ),
    Rule(6, "both", 'v is the integer 1: 1.0, "1" or true are refused (bad_version)'),
    Rule(
        7,
        "both",
        "every field has its JSON type, range and length, never coerced; an id is 1-64 of "
        "A-Z a-z 0-9 _ . - and nothing after (invalid_field, for good)",
    ),
    Rule(8, "ship", "a type the ship does not know, or one only the ship sends, is refused (unknown_type)"),
    Rule(9, "both", "a payload matches the header's size and sha256 (bad_payload, resend)"),
    Rule(
        10,
        "both",
        "a frame is a grayscale PNG or TIFF of the stated size, 8-bit (bit_depth 8) or 16-bit (bad_image)",
    ),
    Rule(
        11,
        "both",
        "a sensor payload is count rows of numbers or null in columns order, t_unix_s never "
        "null, every value in its range (invalid_field)",
    ),
    Rule(
        12,
        "both",
        "hello comes first: the ship answers it with welcome (window, heartbeat_s, ingest, "
        "dive) and refuses data before a welcome (no_hello, resend)",
    ),
    Rule(
        13,
        "both",
        "a module never has more data messages unanswered than the window; the ship refuses "
        "one beyond it (over_window, resend)",
    ),
    Rule(
        14,
        "ship",
        "every data message gets exactly one answer: an ack whose range [boot, first, last] "
        "holds it (both ends inclusive), or one nack naming its boot and seq",
    ),
    Rule(
        15,
        "ship",
        "a message is acknowledged only once stored; the same message again (same header "
        "fields but sent_at and dive, same payload) is acknowledged again and stored once",
    ),
    Rule(
        16,
        "both",
        "(module, boot, seq) names one message forever: a resend keeps its content; the ship "
        "refuses other content under a stored key (conflict), keeps the first and raises an alarm",
    ),
    Rule(
        17,
        "module",
        "a module resends what is unacknowledged after a welcome, after a nack with retry "
        "(later, with a back-off) and when no answer came in time; never after retry false",
    ),
    Rule(
        18,
        "both",
        "answers come in no fixed order (a conflict may come after the answers to later "
        "messages): a module matches them by boot and seq",
    ),
    Rule(
        19,
        "both",
        "each side sends a heartbeat every heartbeat_s; the link is lost after 5 s without a message",
    ),
    Rule(
        20,
        "ship",
        "a heartbeat, a bye of the module's own boot and a valid command_status get no answer; "
        "a bye of another boot is refused (invalid_field) and the module stays linked",
    ),
    Rule(
        21,
        "ship",
        "a nack leaves out boot, seq and of when it could not read them (never null), and its "
        "retry is the reason's",
    ),
    Rule(
        22,
        "ship",
        "a module that holds too much not yet stored on the ship is refused busy (resend after "
        "a pause) and the others are served as usual",
    ),
    Rule(
        23,
        "module",
        "a module answers every command with command_status and applies a command_id at "
        "most once (a repeated one gets its latest status)",
    ),
    Rule(
        24,
        "module",
        "a module sends no data before a welcome and stops sending data after a not_served "
        "or wrong_dive nack until the next welcome",
    ),
)
BY_NUMBER = {r.number: r for r in RULES}


@dataclass
class Verdict:
    """What a kit found about one rule."""

    rule: Rule
    outcome: str = "not checked"  # "pass", "fail" or "not checked"
    notes: list[str] = field(default_factory=list)


class Report:
    """The verdicts of a conformance run, by rule number; a rule fails if any check of it failed."""

    def __init__(self, side: str) -> None:
        self.side = side  # the side being checked: "ship" or "module"
        self.verdicts = {r.number: Verdict(r) for r in RULES if r.binds in (side, "both")}

    def check(self, number: int, ok: bool, note: str = "") -> bool:
        v = self.verdicts[number]
        if not ok:
            v.outcome = "fail"
            v.notes.append(note or "failed")
        elif v.outcome != "fail":
            v.outcome = "pass"
        return ok

    def skip(self, number: int, why: str) -> None:
        v = self.verdicts[number]
        if v.outcome == "not checked":
            v.notes.append(why)

    @property
    def passed(self) -> bool:
        """No rule broken (a rule not checked says why, and breaks nothing)."""
        return not any(v.outcome == "fail" for v in self.verdicts.values())

    def lines(self) -> list[str]:
        """One line per rule: ``R7 pass  ...``; the notes of a failure (or why it was not checked)."""
        out = []
        for n, v in sorted(self.verdicts.items()):
            out.append(f"R{n:<3} {v.outcome:<12} {v.rule.title}")
            out += [f"       {note}" for note in v.notes[:5]]
        failed = sum(v.outcome == "fail" for v in self.verdicts.values())
        unchecked = sum(v.outcome == "not checked" for v in self.verdicts.values())
        out.append(
            f"{self.side}: {len(self.verdicts) - failed - unchecked} rules kept, {failed} broken, "
            f"{unchecked} not checked (docs/protocol.md, 'The rules')"
        )
        return out
