"""An audit entry in one sentence: "what happened", as the review page, its CSV and the export say it.

The audit log keeps each entry's record (actor, action, target, details) as it
was written; the sentence is made from it when it is read, so every reader
(``GET /api/audit``, ``/api/audit/export``, a dive's ``audit_log.csv``) says
the same thing.
"""

from __future__ import annotations

from typing import Any

#: The modules' answers to a command.
ANSWERS = frozenset({"command.accepted", "command.in_progress", "command.done", "command.rejected"})


def lrm(module: str) -> str:
    """``LRM-A`` for module ``A`` (a name that already says LRM is kept)."""
    return module if module.lower().startswith("lrm") else f"LRM-{module}"


def _short_id(command_id: Any) -> str:
    return f"#{str(command_id)[:8]}" if command_id else ""


def _module_of(target: Any) -> str:
    text = str(target or "")
    return lrm(text[7:]) if text.startswith("module:") else text


def _count(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _schedule_text(s: dict[str, Any] | None) -> str:
    if not s:
        return "a schedule"
    grid = " × ".join(
        (
            _count(len(s.get("exposures_s") or []), "exposure"),
            _count(len(s.get("gains_db") or []), "gain"),
            str(s.get("repeats", "?")),
        )
    )
    blocks = s.get("blocks") or []
    more = f" + {_count(len(blocks), 'block')}" if blocks else ""
    waves = "/".join(str(w) for w in s.get("wavelengths_nm") or [])
    return f"{s.get('name', '?')} v{s.get('version', '?')} ({grid}{more} at {waves} nm)"


def describe(entry: dict[str, Any]) -> str:
    """One sentence for an audit entry (``actor``, ``action``, ``target``, ``details``)."""
    action = str(entry.get("action") or "")
    target = str(entry.get("target") or "")
    d = entry.get("details") or {}
    if action in ANSWERS:
        what = (
            "the schedule change" if d.get("action") == "set_schedule" else f"the {d.get('action')} command"
        )
        what = f"{what} {_short_id(d.get('command_id'))}".rstrip()
        m = _module_of(target)
        if action == "command.accepted":
            return f"{m} accepted {what}"
        if action == "command.in_progress":
            return f"{m} accepted {what} and applies it at the end of the current setting"
        if action == "command.done":
            return f"{m} applied {what}"
        return f"{m} rejected {what}: {d.get('reason') or 'no reason given'}"
    if action == "command.set_schedule":
        when = "at the end of the current setting" if d.get("apply") == "end_of_setting" else "now"
        sent = f"sent {_schedule_text(d.get('schedule'))} to {_module_of(target)}, to apply {when}"
        return f"{sent} {_short_id(d.get('command_id'))}".rstrip()
    if action.startswith("command."):
        return f"asked {_module_of(target)} to {action[8:]} {_short_id(d.get('command_id'))}".rstrip()
    if action == "alarm.ack":
        kind = str(d.get("kind") or "").replace("_", " ")
        which = f"({d['key']})" if d.get("key") else target
        return f"acknowledged the {kind} alarm {which}"
    if action == "calibration.add":
        source = f" from {d['source']}" if d.get("source") else ""
        return f"stored calibration {target.removeprefix('calibration:')}{source}"
    if action == "calibration.use":
        return (
            f"{target.replace(':', ' ', 1)} now uses calibration record {d.get('calibration_id')} "
            f"(run {d.get('run_id')})"
        )
    if action == "reanalysis.start":
        cal = f" with calibration record {d['calibration_id']}" if d.get("calibration_id") else ""
        return f"started re-analysis run {d.get('run_id')} of {target.replace(':', ' ', 1)}{cal}"
    return target
