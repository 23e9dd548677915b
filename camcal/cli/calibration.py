"""``camcal calibration``: versioned calibration records in the store."""

from __future__ import annotations

import json
from datetime import datetime
from pathlib import Path
from typing import Annotated

import typer
from rich.table import Table

from camcal.cli.common import DataOption, DbUrlOption, console, fail
from camcal.cli.data import open_store

app = typer.Typer(help="Versioned calibration records: add, list, show.", no_args_is_help=True)


def register(parent: typer.Typer) -> None:
    parent.add_typer(app, name="calibration")


def _time(text: str | None, what: str) -> float | None:
    if not text:
        return None
    from camcal.core.utctime import parse_utc_unix_s

    try:
        return parse_utc_unix_s(text)
    except ValueError as exc:
        raise fail(f"{what}: {exc} (or a date, 2021-09-01; no zone means UTC)") from None


@app.command("add")
def add(
    name: Annotated[str, typer.Option(help="Calibration name, e.g. trex-lab.")],
    result: Annotated[
        list[Path] | None, typer.Option(help="A `camcal calibrate ... --json` result (repeat).")
    ] = None,
    setup: Annotated[
        Path | None,
        typer.Option(help="A setup.json to start from (default: the name's newest version, else T-REX)."),
    ] = None,
    valid_from: Annotated[str | None, typer.Option(help="Valid from (ISO UTC).")] = None,
    valid_to: Annotated[str | None, typer.Option(help="Valid until (ISO UTC).")] = None,
    actor: Annotated[str, typer.Option(help="Who adds it (for the audit log).")] = "cli",
    data: DataOption = None,
    db_url: DbUrlOption = None,
) -> None:
    """Store a new version of a calibration from lab results and/or a setup.json."""
    from camcal.core.calibrations import CalibrationError, load_json, merge_results, record_values
    from camcal.core.frameset import FrameSetError, Setup, parse_setup
    from storage import queries

    store = open_store(data, db_url, create=True)
    try:
        if setup is not None:
            try:
                base = parse_setup(json.loads(setup.read_text()), str(setup))
            except (OSError, ValueError, FrameSetError) as exc:
                raise fail(f"{setup}: {exc}") from None
        else:
            prev = store.call(queries.calibration, name)
            base = parse_setup(prev["values"]["setup"], name) if prev else Setup()
        try:
            merged, rows, sources = merge_results(base, [load_json(p) for p in result or []])
        except CalibrationError as exc:
            raise fail(str(exc)) from None
        if setup is not None:
            sources.insert(0, f"setup {setup}")
        rec = store.add_calibration(
            name,
            record_values(merged, rows, sources),
            actor=actor,
            source="; ".join(sources),
            valid_from_unix_s=_time(valid_from, "--valid-from"),
            valid_to_unix_s=_time(valid_to, "--valid-to"),
        )
    finally:
        store.close()
    console.print(f"calibration {rec['name']} version {rec['version']} stored (id {rec['id']})")


@app.command("list")
def list_cmd(
    name: Annotated[str | None, typer.Option(help="Only this name.")] = None,
    data: DataOption = None,
    db_url: DbUrlOption = None,
) -> None:
    """Every stored calibration version."""
    from storage import queries

    store = open_store(data, db_url)
    try:
        cals = store.call(queries.calibrations, name)
    finally:
        store.close()
    t = Table(title="calibrations", title_justify="left")
    for col in (
        "id",
        "name",
        "version",
        "valid from",
        "valid to",
        "I0'/I0 (405/460/525)",
        "linear range",
        "source",
    ):
        t.add_column(col)
    for c in cals:
        st = c["values"]["setup"]
        ratios = "/".join(
            f"{st['emission_ratio'].get(str(w), {}).get('value', '—')}" for w in (405, 460, 525)
        )
        fmt = lambda x: datetime.utcfromtimestamp(x).strftime("%Y-%m-%d") if x else "—"  # noqa: E731
        t.add_row(
            str(c["id"]),
            c["name"],
            str(c["version"]),
            fmt(c["valid_from_unix_s"]),
            fmt(c["valid_to_unix_s"]),
            ratios,
            f"{st['linear_range'][0]:g}–{st['linear_range'][1]:g}",
            c["source"][:60],
        )
    console.print(t)


@app.command("show")
def show(
    ref: Annotated[str, typer.Argument(help="NAME, NAME@VERSION or an id.")],
    data: DataOption = None,
    db_url: DbUrlOption = None,
) -> None:
    """One calibration record as JSON."""
    from storage import queries

    store = open_store(data, db_url)
    try:
        rec = store.call(queries.calibration, ref)
    finally:
        store.close()
    if rec is None:
        raise fail(f"no calibration {ref!r}")
    console.print_json(json.dumps(rec))
