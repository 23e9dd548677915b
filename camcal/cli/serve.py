"""``camcal serve`` (the web server) and ``camcal up`` (the whole system on one machine)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from camcal.cli.common import console, fail
from camcal.cli.config import settings_or_fail
from camcal.cli.credentials import child_environment, operator_tokens, simulated_link, tokens_or_generated
from camcal.logs import configure_logging
from camcal.settings import Settings


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)
    app.command("up")(up)


def run_server(settings: Settings, tokens: dict[str, str], events: str | None) -> None:
    import uvicorn

    from server.app import create_app
    from server.settings import ServerSettings

    app = create_app(
        ServerSettings(
            data_dir=settings.data_dir,
            db_url=settings.database_url,
            events=events,
            operator_tokens=tokens,
            linear_range=settings.linear_range,
            station_depth_m=settings.station_depth_m,
            max_body_bytes=int(settings.http_max_body_mb * 1024 * 1024),
            max_websockets_per_client=settings.http_max_connections_per_client,
            max_requests_per_client=2 * settings.http_max_connections_per_client,
        )
    )
    tls = tls_files(settings)
    # No permessage-deflate: compressing every event once per browser costs the ship more CPU than
    # the bytes it saves on its own network (events are a few hundred bytes of JSON).
    config = uvicorn.Config(
        app,
        host=settings.http_host,
        port=settings.http_port,
        log_level="warning",
        ws_ping_interval=20,
        ws_per_message_deflate=False,
        ws_max_size=64 * 1024,  # a browser sends a few small requests; nothing needs more
        ssl_certfile=str(tls[0]) if tls else None,
        ssl_keyfile=str(tls[1]) if tls else None,
    )
    try:
        uvicorn.Server(config).run()
    except OSError as exc:
        raise fail(f"cannot serve on {settings.http_host}:{settings.http_port}: {exc}") from None


def tls_files(settings: Settings) -> tuple[Path, Path] | None:
    """The TLS certificate and key (``http_tls_cert``, ``http_tls_key``), both or neither, readable."""
    cert, key = settings.http_tls_cert, settings.http_tls_key
    if cert is None and key is None:
        return None
    if cert is None or key is None:
        raise fail("TLS needs both http_tls_cert and http_tls_key (--tls-cert, --tls-key)")
    for what, path in (("certificate", cert), ("key", key)):
        if not path.is_file():
            raise fail(f"TLS {what} {path} is not a readable file")
    return cert, key


def serve(
    data: Annotated[Path | None, typer.Option(help="Data folder [CAMCAL_DATA_DIR].")] = None,
    host: Annotated[
        str | None, typer.Option(help="Address; 0.0.0.0 for the ship's network [CAMCAL_HTTP_HOST].")
    ] = None,
    port: Annotated[int | None, typer.Option(help="HTTP port [CAMCAL_HTTP_PORT].")] = None,
    events: Annotated[
        str | None, typer.Option(help="The ingest's events; 'none' for review only [CAMCAL_EVENTS_CONNECT].")
    ] = None,
    db_url: Annotated[str | None, typer.Option(help="SQLAlchemy URL [CAMCAL_DATABASE_URL].")] = None,
    operator_token: Annotated[
        list[str] | None,
        typer.Option(help="NAME=TOKEN of an operator (repeat); shown by ps: use CAMCAL_OPERATOR_TOKENS."),
    ] = None,
    tls_cert: Annotated[
        Path | None, typer.Option(help="TLS certificate (PEM): serve HTTPS [CAMCAL_HTTP_TLS_CERT].")
    ] = None,
    tls_key: Annotated[
        Path | None, typer.Option(help="The certificate's private key (PEM) [CAMCAL_HTTP_TLS_KEY].")
    ] = None,
    config: Annotated[Path | None, typer.Option(help="A TOML configuration file [CAMCAL_CONFIG].")] = None,
) -> None:
    """Serve the dashboard and the API (OpenAPI at /docs) for a data folder."""
    s = settings_or_fail(
        config,
        data_dir=data,
        http_host=host,
        http_port=port,
        events_connect=events,
        database_url=db_url,
        http_tls_cert=tls_cert,
        http_tls_key=tls_key,
    )
    configure_logging(s.log_level, s.log_format)
    tokens = operator_tokens(operator_token, s)
    scheme = "https" if tls_files(s) else "http"
    console.print(
        f"camcal server: {scheme}://{s.http_host}:{s.http_port}  (API docs at /docs; data {s.data_dir})"
    )
    run_server(s, tokens, None if s.events_connect == "none" else s.events_connect)


def _spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("ab") as fh:
        return subprocess.Popen(
            [sys.executable, "-c", "from camcal.cli import main; main()", *args],
            stdout=fh,
            stderr=fh,
            start_new_session=True,
            env=child_environment(),  # the children need no operator token
        )


def up(
    data: Annotated[Path | None, typer.Option(help="Data folder; an open dive there is continued.")] = None,
    port: Annotated[int | None, typer.Option(help="Dashboard port [CAMCAL_HTTP_PORT].")] = None,
    host: Annotated[str | None, typer.Option(help="Dashboard address [CAMCAL_HTTP_HOST].")] = None,
    ingest_port: Annotated[int, typer.Option(help="Port modules connect to.")] = 5555,
    events_port: Annotated[int, typer.Option(help="Port of the ingest's event publisher.")] = 5556,
    simulate: Annotated[bool, typer.Option(help="Run two simulated modules (A and B).")] = True,
    speed: Annotated[float, typer.Option(help="Speed of the simulated dive.")] = 10.0,
    frame_scale: Annotated[float, typer.Option(help="Simulated sensor scale (1 = 5 MP).")] = 0.5,
    schedule: Annotated[str, typer.Option(help="Schedule of the simulated modules.")] = "trex-subsampled",
    seed: Annotated[int, typer.Option(help="Seed of the simulated dive.")] = 0,
    deck_s: Annotated[
        float, typer.Option(help="Simulated time on deck before the descent, in seconds.")
    ] = 60.0,
    winch_m_per_s: Annotated[float, typer.Option(help="Simulated descent and ascent speed, in m/s.")] = 1.0,
    test_stop_s: Annotated[
        float, typer.Option(help="Simulated time at each test stop (1200 m, 2021 m), in seconds.")
    ] = 120.0,
    station_s: Annotated[
        float, typer.Option(help="Simulated time on station at 3420 m, in seconds.")
    ] = 1800.0,
    operator_token: Annotated[
        list[str] | None, typer.Option(help="NAME=TOKEN of an operator (repeat).")
    ] = None,
    config: Annotated[Path | None, typer.Option(help="A TOML configuration file [CAMCAL_CONFIG].")] = None,
) -> None:
    """Start the whole system: ingest, two simulated modules on a simulated dive, and the dashboard."""
    s = settings_or_fail(config, data_dir=data, http_host=host, http_port=port)
    configure_logging(s.log_level, s.log_format)
    data_dir = s.data_dir
    data_dir.mkdir(parents=True, exist_ok=True)
    logs = data_dir / "logs"
    logs.mkdir(exist_ok=True)
    tokens, generated = tokens_or_generated(operator_token, s)
    events = f"tcp://127.0.0.1:{events_port}"
    link = simulated_link(s, ["A", "B"]) if simulate else []
    dive = up_dive(s)
    link += ["--dive", dive]
    # SIGTERM (docker stop, systemd, kill) must stop the children too. uvicorn handles the signal,
    # shuts down, then raises it again: with the default action this process would die before the
    # `finally` below stops the ingest and the modules.
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    children: list[tuple[str, subprocess.Popen[bytes]]] = [
        (
            "ingest",
            _spawn(
                [
                    "ingest",
                    "--data",
                    str(data_dir),
                    "--bind",
                    f"tcp://127.0.0.1:{ingest_port}",
                    "--events",
                    events,
                    "--dive",
                    dive,
                ],
                logs / "ingest.log",
            ),
        ),
    ]
    try:
        if simulate:
            epoch = time.time() + 3.0
            for m in ("A", "B"):
                children.append(
                    (
                        f"module {m}",
                        _spawn(
                            [
                                "lrm",
                                "simulate",
                                "--camera",
                                m,
                                "--connect",
                                f"tcp://127.0.0.1:{ingest_port}",
                                "--outbox",
                                str(data_dir / f"outbox-{m}"),
                                "--speed",
                                str(speed),
                                "--frame-scale",
                                str(frame_scale),
                                "--schedule",
                                schedule,
                                "--seed",
                                str(seed),
                                "--epoch",
                                str(epoch),
                                "--deck-s",
                                str(deck_s),
                                "--winch-m-per-s",
                                str(winch_m_per_s),
                                "--test-stop-s",
                                str(test_stop_s),
                                "--station-s",
                                str(station_s),
                                *link,
                            ],
                            logs / f"module-{m}.log",
                        ),
                    )
                )
        console.print(
            f"[bold]camcal is up:[/] dashboard http://{s.http_host}:{s.http_port}  "
            "(review: /review, API: /docs)"
        )
        console.print(f"data: {data_dir}   logs: {logs}   modules connect to tcp://<this host>:{ingest_port}")
        if generated:  # a token camcal made up is shown once; a configured one never is
            for name, token in tokens.items():
                console.print(f"operator token for {name}: {token}")
        console.print("stop with Ctrl-C")
        if simulate and s.station_depth_m is None:  # the simulated dive's plan
            from lrm.dive import DiveProfile

            s = s.model_copy(update={"station_depth_m": DiveProfile().station_depth_m})
        run_server(s, tokens, events)
    finally:
        stop_children(children)


def up_dive(settings: Settings) -> str:
    """The dive ``camcal up`` records into (the configured one, else the open one, else a new one),
    named to the ingest and the simulated modules alike: a module refuses an ingest of another dive."""
    from storage.store import Store

    try:
        store = Store.open(settings.data_dir, settings.database_url)  # also creates or migrates it
    except Exception as exc:
        raise fail(f"cannot open the store in {settings.data_dir}: {exc}") from None
    try:
        dive = store.current_dive(create=True, name=settings.dive)
        assert dive is not None
        return dive.name
    finally:
        store.close()


def _exit_on_sigterm(signum: int, _frame: object) -> None:
    raise SystemExit(0)


def stop_children(children: list[tuple[str, subprocess.Popen[bytes]]]) -> None:
    """Modules first (they finish writing their outbox), then the ingest (it commits what it has)."""
    for _name, proc in reversed(children):
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
    console.print("stopped: " + ", ".join(f"{n} ({p.returncode})" for n, p in children))
