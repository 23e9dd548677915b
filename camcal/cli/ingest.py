"""``camcal ingest``: the ship-side service that receives, stores and analyses."""

from __future__ import annotations

import logging
import re
import signal
import threading
from pathlib import Path
from typing import Annotated

import typer

from camcal.cli.common import console, fail
from camcal.frameset import FrameSetError, Setup, read_setup


def register(app: typer.Typer) -> None:
    app.command("ingest")(ingest)


def load_setup(setup: Path | None) -> Setup:
    """A setup.json file (or a frame-set folder holding one), or the T-REX defaults."""
    if setup is None:
        return Setup()
    folder = setup if setup.is_dir() else setup.parent
    if not setup.is_dir() and setup.name != "setup.json":
        import json

        from camcal.frameset import parse_setup

        try:
            return parse_setup(json.loads(setup.read_text()), str(setup))
        except (OSError, ValueError) as exc:
            raise fail(f"{setup}: {exc}") from None
    try:
        return read_setup(folder)
    except FrameSetError as exc:
        raise fail(str(exc)) from None


def parse_modules(text: str | None) -> tuple[str, ...]:
    """``"A,B"`` -> ``("A", "B")``; each a valid module id."""
    if not text:
        return ()
    out = tuple(dict.fromkeys(m.strip() for m in text.split(",") if m.strip()))
    bad = [m for m in out if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", m)]
    if bad or not out:
        raise fail(f"--modules: expected module ids such as A,B (letters, digits, _ . -), got {text!r}")
    return out


def ingest(
    data: Annotated[Path, typer.Option(help="Data folder (database and frame files).")] = Path("camcal-data"),
    bind: Annotated[str, typer.Option(help="Where modules connect: tcp://*:PORT.")] = "tcp://*:5555",
    events: Annotated[
        str, typer.Option(help="Where the dashboard subscribes to events.")
    ] = "tcp://127.0.0.1:5556",
    db_url: Annotated[
        str | None, typer.Option(help="SQLAlchemy URL (default: SQLite in the data folder).")
    ] = None,
    setup: Annotated[
        Path | None, typer.Option(help="setup.json with distances, I0'/I0, linear range.")
    ] = None,
    dive: Annotated[
        str | None, typer.Option(help="Name of the dive to record into (default: the open one).")
    ] = None,
    modules: Annotated[
        str | None,
        typer.Option(
            help="Modules this process serves, comma-separated (default: any). Required when several "
            "ingests share one database: each module is served by exactly one; others are refused."
        ),
    ] = None,
    workers: Annotated[int, typer.Option(help="Analysis processes (default: all cores).")] = 0,
    window: Annotated[
        int, typer.Option(help="Credit: unacknowledged messages a module may have in flight.")
    ] = 8,
    fsync: Annotated[bool, typer.Option(help="fsync every frame file before acknowledging it.")] = True,
    log_level: Annotated[str, typer.Option(help="debug, info, warning.")] = "info",
) -> None:
    """Receive frames and sensor packets from the modules, store, analyse and publish them."""
    from ingest.service import IngestConfig, IngestService

    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    served = parse_modules(modules)
    cfg = IngestConfig(
        data_dir=data,
        bind=bind,
        events_bind=events,
        db_url=db_url,
        setup=load_setup(setup),
        dive_name=dive,
        workers=workers,
        window=window,
        fsync=fsync,
        modules=served,
    )
    try:
        svc = IngestService(cfg)
        svc.start()
    except Exception as exc:  # bad URL, port in use, unwritable folder: say so in one line
        raise fail(f"cannot start the ingest: {exc}") from None
    console.print(
        f"ingest: modules connect to {svc.endpoint}; events on {svc.events_endpoint}; "
        f"dive {svc.dive.name}; data in {data}" + (f"; serving {', '.join(served)}" if served else "")
    )
    done = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    while not done.wait(0.5):
        if svc.error is not None:
            break
    svc.stop()
    if svc.error is not None:
        raise fail(f"ingest stopped after an error: {svc.error}", code=1)
    console.print("ingest stopped cleanly")
