"""``camcal ingest``: the ship-side service that receives, stores and analyses."""

from __future__ import annotations

import contextlib
import json
import logging
import re
import signal
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from camcal.cli.common import DataOption, DbUrlOption, console, fail
from camcal.cli.config import settings_or_fail
from camcal.core import runfile, supervise
from camcal.core.logs import configure_logging

if TYPE_CHECKING:
    from camcal.core.frameset import Setup
    from camcal.core.settings import Settings


def register(app: typer.Typer) -> None:
    app.command("ingest")(ingest)


def load_setup(setup: Path | None, settings: Settings) -> Setup:
    """A setup.json file (or a frame-set folder holding one), else the configured modules and ratios."""
    from camcal.core.frameset import FrameSetError, parse_setup, read_setup

    if setup is None:
        return settings.setup()
    if setup.is_dir():
        try:
            return read_setup(setup)
        except FrameSetError as exc:
            raise fail(str(exc)) from None
    try:
        return parse_setup(json.loads(setup.read_text()), str(setup))
    except FrameSetError as exc:
        raise fail(str(exc)) from None
    except (OSError, ValueError) as exc:
        raise fail(f"{setup}: {exc}") from None


def alarm_limits(settings: Settings):
    from ingest.alarms import AlarmLimits

    return AlarmLimits(**settings.alarms.model_dump())


def parse_modules(text: str | None) -> tuple[str, ...]:
    """``"A,B"`` -> ``("A", "B")``; each a valid module id."""
    if not text:
        return ()
    out = tuple(dict.fromkeys(m.strip() for m in text.split(",") if m.strip()))
    bad = [m for m in out if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", m)]
    if bad or not out:
        raise fail(f"--modules: expected module ids such as A,B (letters, digits, _ . -), got {text!r}")
    return out


def start_service(cfg: Any, settings: Settings | None = None) -> Any:
    """Check the ports, choose the dive (with ``settings``: `camcal.cli.dive.dive_for_start`), then
    start an `IngestService`; a failure is one line (and exit status 3), told to a supervising
    `camcal up` too, with nothing left running."""
    from dataclasses import replace

    from camcal.cli.dive import dive_for_start
    from ingest.service import IngestService

    svc = None
    try:
        supervise.check_endpoint(cfg.bind, part="ingest", setting="--bind (CAMCAL_INGEST_BIND)")
        if cfg.events_bind:
            supervise.check_endpoint(
                cfg.events_bind, part="ingest's event publisher", setting="--events (CAMCAL_EVENTS_BIND)"
            )
        if settings is not None:  # the named dive, the open one still in the water, or a new one
            name, line = dive_for_start(settings.model_copy(update={"dive": cfg.dive_name}))
            console.print(line)
            cfg = replace(cfg, dive_name=name)
        svc = IngestService(cfg)
        svc.start()
        return svc
    except Exception as exc:  # bad URL, port in use, unwritable folder: say so in one line
        message = str(exc) if isinstance(exc, supervise.PortInUse) else f"cannot start the ingest: {exc}"
        supervise.notify_error(message)
        if svc is not None:
            with contextlib.suppress(Exception):
                svc.stop(timeout=2.0)
        raise fail(message, code=supervise.EXIT_NOT_STARTED) from None


def ingest(
    data: DataOption = None,
    bind: Annotated[
        str | None, typer.Option(help="Where modules connect, tcp://*:PORT [CAMCAL_INGEST_BIND].")
    ] = None,
    events: Annotated[
        str | None, typer.Option(help="Event publisher for the dashboard [CAMCAL_EVENTS_BIND].")
    ] = None,
    db_url: DbUrlOption = None,
    setup: Annotated[
        Path | None, typer.Option(help="setup.json with distances, I0'/I0, linear range.")
    ] = None,
    dive: Annotated[
        str | None,
        typer.Option(help="Name of the dive to record into [CAMCAL_DIVE; default: the open one]."),
    ] = None,
    modules: Annotated[
        str | None,
        typer.Option(
            help="Modules this process serves, comma-separated (default: any). Required when several "
            "ingests share one database: each module is served by exactly one; others are refused."
        ),
    ] = None,
    workers: Annotated[
        int | None, typer.Option(help="Analysis processes (0: all cores) [CAMCAL_WORKERS].")
    ] = None,
    window: Annotated[int | None, typer.Option(help="Credit per module [CAMCAL_WINDOW].")] = None,
    fsync: Annotated[
        bool | None, typer.Option(help="fsync frame files before acknowledging [CAMCAL_FSYNC].")
    ] = None,
    keys: Annotated[
        Path | None,
        typer.Option(help="The link's CURVE keys, `camcal keys create` [CAMCAL_KEYS_DIR; <data>/keys]."),
    ] = None,
    plaintext: Annotated[
        bool | None,
        typer.Option(help="No keys, no encryption: a lab bench only [CAMCAL_LINK_PLAINTEXT]."),
    ] = None,
    conformance: Annotated[
        bool,
        typer.Option(
            help="Store nothing: check the module that connects against the rules of docs/protocol.md, "
            "print pass or fail per rule, exit (0: none broken)."
        ),
    ] = False,
    conformance_s: Annotated[
        float, typer.Option(help="With --conformance: how long to wait for the module at most [s].")
    ] = 60.0,
    config: Annotated[Path | None, typer.Option(help="A TOML configuration file [CAMCAL_CONFIG].")] = None,
    log_level: Annotated[str | None, typer.Option(help="debug, info, warning [CAMCAL_LOG_LEVEL].")] = None,
) -> None:
    """Receive frames and sensor packets from the modules, store, analyse and publish them.

    Modules connect over ZeroMQ CURVE: each with its own key, which the ingest lets in as
    that module only (`camcal keys create A B` makes the keys)."""
    from ingest.service import IngestConfig

    served = parse_modules(modules)
    s = settings_or_fail(
        config,
        data_dir=data,
        ingest_bind=bind,
        events_bind=events,
        database_url=db_url,
        workers=workers,
        window=window,
        fsync=fsync,
        log_level=log_level,
        keys_dir=keys,
        link_plaintext=plaintext,
    )
    configure_logging(s.log_level, s.log_format)
    if conformance:
        from camcal.cli.lrm_conformance import ingest_conformance

        ingest_conformance(s.ingest_bind, s.keys_path(), s.link_plaintext, dive or s.dive, conformance_s)
        return
    cfg = IngestConfig(
        data_dir=s.data_dir,
        bind=s.ingest_bind,
        events_bind=s.events_bind,
        events_curve=s.events_curve,
        db_url=s.database_url,
        setup=load_setup(setup, s),
        dive_name=dive or s.dive,
        workers=s.workers,
        window=s.window,
        max_payload_bytes=int(s.max_payload_mb * 1024 * 1024),
        module_queue_bytes=int(s.module_queue_mb * 1024 * 1024),
        fsync=s.fsync,
        sqlite_synchronous=s.sqlite_synchronous,
        alarm_limits=alarm_limits(s),
        retention_days=s.retention_days,
        modules=served,
        keys_dir=s.keys_path(),
        plaintext=s.link_plaintext,
    )
    done = threading.Event()  # SIGTERM or Ctrl-C, even while starting: stop in order, exit 0

    def on_signal(signum: int, _frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    svc = start_service(cfg, s)
    console.print(
        f"ingest: modules connect to {svc.endpoint}; events on {svc.events_endpoint}; "
        f"dive {svc.dive.name}; data in {s.data_dir}"
        + (f"; serving {', '.join(served)}" if served else "")
        + ("; PLAINTEXT link (lab bench only)" if s.link_plaintext else f"; keys in {s.keys_path()}")
    )
    supervise.notify_ready(
        f"dive {svc.dive.name}, modules connect to {svc.endpoint}",
        endpoint=svc.endpoint,
        events=svc.events_endpoint,
        dive=svc.dive.name,
    )
    run_file = runfile.write(
        s.data_dir,
        "ingest",
        {
            "ingest_bind": svc.endpoint,
            "events_bind": svc.events_endpoint,
            "events_curve": bool(svc.publisher and svc.publisher.curve),
            "modules": list(served),
            "link_plaintext": s.link_plaintext,
        },
    )  # what `camcal doctor` checks
    while not done.wait(0.5):
        if svc.error is not None:
            break
    runfile.remove(run_file)
    svc.stop(timeout=4.0)  # what did not finish by then is safe: modules resend what was not acknowledged
    if svc.error is not None:
        raise fail(f"ingest stopped after an error: {svc.error}", code=supervise.EXIT_FAILED)
    logging.getLogger("camcal.ingest").info("ingest stopped cleanly")
    console.print("ingest stopped cleanly")
