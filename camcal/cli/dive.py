"""``camcal dive``: the dives in the store, and ending one so that the next deployment is a new dive.

An ingest (and ``camcal up``) without a dive name records into the open
dive, the newest one not ended, and starts a new one when there is none or
when the open one is over by what its modules did: back on deck and signed
off, or back on deck with no frame for ``dive_quiet_s``
(`storage.queries.divestate`). A dive still in the water is continued, so a
restart in the middle of a dive does not split it. `dive_for_start` is that
choice, for ``camcal up`` and ``camcal ingest`` alike.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from camcal.cli.common import DataOption, DbUrlOption, console, fail
from camcal.cli.data import open_store, store_location

if TYPE_CHECKING:
    from camcal.core.settings import Settings
    from storage.queries.divestate import DiveRules

app = typer.Typer(help="The dives in the store: list them, end one.", no_args_is_help=True)

#: Frames received into a dive this recently may come from an ingest still recording into it.
RECORDING_S = 120.0


def register(parent: typer.Typer) -> None:
    parent.add_typer(app, name="dive")


def _recording_here(data: Path) -> list[str]:
    """The ``camcal ingest`` and ``camcal up`` processes on this machine that may record into the
    store of ``data`` (one naming another ``--data`` folder does not), as "pid N: camcal ..."."""
    from camcal.core import procinfo

    out = []
    for c in procinfo.camcal_processes():
        if c.kind not in ("camcal ingest", "camcal up") or c.leftover:
            continue
        words = c.args.split()
        if "--data" in words[:-1] and Path(words[words.index("--data") + 1]).resolve() != data.resolve():
            continue
        out.append(f"pid {c.process.pid}: camcal {procinfo.short(c.args, 60)}")
    return out


def dive_rules(settings: Settings) -> DiveRules:
    """When a dive is over, as configured (``deck_depth_m``, ``dive_quiet_s``)."""
    from storage.queries.divestate import DiveRules

    return DiveRules(deck_depth_m=settings.deck_depth_m, quiet_s=settings.dive_quiet_s)


def dive_for_start(settings: Settings) -> tuple[str, str]:
    """The dive a start records into (the configured one, else the open one, else a new one) and a
    line saying which: new, continued (with how long ago its last frame arrived), or new because the
    open one is over (and why). Opens (creates or migrates) the store first."""
    from storage import queries
    from storage.store import Store

    store = Store.open(settings.data_dir, settings.database_url)
    try:
        choice = store.dive_to_record(settings.dive, rules=dive_rules(settings))
        received = store.call(queries.last_received_unix_s, choice.dive.id)
    finally:
        store.close()
    name = choice.dive.name
    before = ""
    if choice.ended is not None:
        old, state = choice.ended
        before = f"dive {old} has ended ({state.reason}); "
    if choice.reopened is not None:
        before = f"dive {name} had ended ({choice.reopened}); recording into it again as configured; "
    if choice.new:
        return name, f"{before}dive {name}: new"
    line = f"{before}dive {name}: continued"
    if received is not None:
        # the ship's own clock: never a negative age from a module's clock running ahead
        line += f" (its last frame arrived {_ago(time.time() - received)} ago)"
    if settings.dive is None:
        line += (
            "; it is still in the water by its modules' depths. A new deployment? stop, run "
            "`camcal dive end`, start again"
        )
    return name, line


def _ago(seconds: float) -> str:
    seconds = max(0.0, seconds)
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _span(t0: float | None, t1: float | None) -> str:
    """``2026-11-27 22:28–22:30`` (the end's date too when it is another day)."""
    if not t0 or not t1:
        return "—"
    a, b = _utc(t0)[:16], _utc(t1)[:16]
    return f"{a}–{b[11:] if a[:10] == b[:10] else b}"


def _utc(t: float | None) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(t)) if t else "—"


@app.command("list")
def list_cmd(
    data: DataOption = None,
    db_url: DbUrlOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the dives as JSON.")] = False,
) -> None:
    """Every dive, newest first: frames, time span, deepest frame, open or ended."""
    from camcal.cli.config import settings_or_fail
    from storage import queries

    rules = dive_rules(settings_or_fail(None, data_dir=data, database_url=db_url))
    store = open_store(data, db_url)
    try:
        dives = store.call(queries.dives, None, rules)
    finally:
        store.close()
    if as_json:
        print(json.dumps(dives, indent=1))
        return
    rows = [("id", "name", "frames", "received (UTC)", "deepest", "state")]
    for d in dives:
        rows.append(
            (
                str(d["id"]),
                d["name"],
                str(d["n_frames"]),
                _span(d["first_received_unix_s"], d["last_received_unix_s"]),
                f"{d['max_depth_m']:.0f} m" if d["max_depth_m"] is not None else "—",
                _state(d),
            )
        )
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    right = {0, 2, 4}  # numbers
    for r in rows:  # plain columns: a table squeezed into 80 columns cut the names
        cells = [
            c.rjust(w) if k in right else c.ljust(w) for k, (c, w) in enumerate(zip(r, widths, strict=True))
        ]
        console.print("  ".join(cells).rstrip(), highlight=False, soft_wrap=True)


def _state(d: dict[str, object]) -> str:
    """``open: in the water (A at 3420 m)`` / ``ended 2026-11-28 02:10: back on deck and signed off``."""
    if d["state"] == "ended":
        t = d["state_ended_unix_s"]
        return f"ended {_utc(t)[:16] if isinstance(t, float) else ''}: {d['state_reason']}"
    return f"open: {d['state_reason']}"


@app.command("end")
def end(
    name: Annotated[str | None, typer.Argument(help="The dive to end (default: the open one).")] = None,
    force: Annotated[
        bool, typer.Option(help="End it although frames are still arriving into it (an ingest is running).")
    ] = False,
    actor: Annotated[str, typer.Option(help="Who ends it (for the audit log).")] = "cli",
    data: DataOption = None,
    db_url: DbUrlOption = None,
) -> None:
    """End a dive: the next ingest or `camcal up` without a dive name records into a new one."""
    from storage import queries

    store = open_store(data, db_url)
    try:
        dive = store.call(queries.dive_by_name, name) if name else store.current_dive(create=False)
        if dive is None:
            raise fail(f"no dive named {name!r} (`camcal dive list` lists them)" if name else "no open dive")
        if dive.ended_unix_s:
            console.print(f"dive {dive.name} ended at {_utc(dive.ended_unix_s)} UTC already: nothing to do")
            return
        record = store.call(queries.dive_record, dive.id) or {}
        folder, url = store_location(data, db_url)
        shared = url is not None and not url.startswith("sqlite")  # other machines may record into it
        recorders = _recording_here(folder)
        if recorders and not force:
            raise fail(
                f"an ingest on this machine may be recording into dive {dive.name} "
                f"({'; '.join(recorders)}): stop it first (Ctrl-C on `camcal up` or `camcal ingest`), then "
                "end the dive; --force ends it anyway (the running ingest keeps recording into it until it "
                "restarts)",
                code=1,
            )
        received = store.call(queries.last_received_unix_s, dive.id)
        store.end_dive(dive.id, reason=f"ended by {actor} (camcal dive end)")
        store.audit(
            actor,
            "dive.end",
            dive.name,
            {"n_frames": record.get("n_frames", 0), "last_frame_unix_s": record.get("last_frame_unix_s")},
        )
    finally:
        store.close()
    ago = time.time() - received if received else None
    if shared and ago is not None and ago < RECORDING_S and not recorders:
        console.print(
            f"note: its last frame arrived {ago:.0f} s ago; an ingest on another machine (a shared "
            "database) keeps recording into it until that ingest restarts"
        )
    console.print(
        f"dive {dive.name} ended ({record.get('n_frames', 0)} frames, the last at "
        f"{_utc(record.get('last_frame_unix_s'))} UTC): the next `camcal up` or `camcal ingest` without a "
        "dive name records into a new dive"
    )
