"""``camcal serve`` (the web server) and ``camcal up`` (the whole system on one machine)."""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Annotated

import typer

from camcal.cli.common import console, fail


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)
    app.command("up")(up)


def operator_tokens(items: list[str] | None) -> dict[str, str]:
    """``NAME=TOKEN`` items, plus ``CAMCAL_OPERATOR_TOKENS`` (comma-separated ``NAME=TOKEN``)."""
    out: dict[str, str] = {}
    for item in [*(os.environ.get("CAMCAL_OPERATOR_TOKENS", "").split(",")), *(items or [])]:
        item = item.strip()
        if not item:
            continue
        name, sep, token = item.partition("=")
        if not sep or not name or len(token) < 8:
            raise fail("operator tokens are NAME=TOKEN with a token of at least 8 characters")
        out[name] = token
    return out


def run_server(
    data: Path, host: str, port: int, events: str | None, tokens: dict[str, str], db_url: str | None = None
) -> None:
    import uvicorn

    from server.app import create_app
    from server.settings import ServerSettings

    app = create_app(ServerSettings(data_dir=data, db_url=db_url, events=events, operator_tokens=tokens))
    # No permessage-deflate: compressing every event once per browser costs the ship more CPU than
    # the bytes it saves on its own network (events are a few hundred bytes of JSON).
    config = uvicorn.Config(
        app, host=host, port=port, log_level="warning", ws_ping_interval=20, ws_per_message_deflate=False
    )
    server = uvicorn.Server(config)
    try:
        server.run()
    except OSError as exc:
        raise fail(f"cannot serve on {host}:{port}: {exc}") from None


def serve(
    data: Annotated[Path, typer.Option(help="Data folder (database and frame files).")] = Path("camcal-data"),
    host: Annotated[
        str, typer.Option(help="Address to listen on (0.0.0.0 for the ship's network).")
    ] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="HTTP port.")] = 8000,
    events: Annotated[
        str, typer.Option(help="The ingest's event publisher; 'none' for review only.")
    ] = "tcp://127.0.0.1:5556",
    db_url: Annotated[
        str | None, typer.Option(help="SQLAlchemy URL (default: SQLite in the data folder).")
    ] = None,
    operator_token: Annotated[
        list[str] | None, typer.Option(help="NAME=TOKEN of an operator (repeat).")
    ] = None,
) -> None:
    """Serve the dashboard and the API (OpenAPI at /docs) for a data folder."""
    tokens = operator_tokens(operator_token)
    console.print(f"camcal server: http://{host}:{port}  (API docs at /docs; data {data})")
    run_server(data, host, port, None if events == "none" else events, tokens, db_url)


def _spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    with log.open("ab") as fh:
        return subprocess.Popen(
            [sys.executable, "-c", "from camcal.cli import main; main()", *args],
            stdout=fh,
            stderr=fh,
            start_new_session=True,
        )


def up(
    data: Annotated[Path, typer.Option(help="Data folder; an open dive there is continued.")] = Path(
        "camcal-data"
    ),
    port: Annotated[int, typer.Option(help="Dashboard port.")] = 8000,
    host: Annotated[str, typer.Option(help="Dashboard address.")] = "127.0.0.1",
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
) -> None:
    """Start the whole system: ingest, two simulated modules on a simulated dive, and the dashboard."""
    data.mkdir(parents=True, exist_ok=True)
    logs = data / "logs"
    logs.mkdir(exist_ok=True)
    tokens = operator_tokens(operator_token)
    if not tokens:
        tokens = {"operator": secrets.token_urlsafe(12)}
    events = f"tcp://127.0.0.1:{events_port}"
    from storage.store import Store

    try:
        Store.open(data).close()  # create or migrate the database before anyone uses it
    except Exception as exc:
        raise fail(f"cannot open the store in {data}: {exc}") from None
    children: list[tuple[str, subprocess.Popen[bytes]]] = [
        (
            "ingest",
            _spawn(
                [
                    "ingest",
                    "--data",
                    str(data),
                    "--bind",
                    f"tcp://127.0.0.1:{ingest_port}",
                    "--events",
                    events,
                ],
                logs / "ingest.log",
            ),
        ),
    ]
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
                            str(data / f"outbox-{m}"),
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
                        ],
                        logs / f"module-{m}.log",
                    ),
                )
            )
    console.print(f"[bold]camcal is up:[/] dashboard http://{host}:{port}  (review: /review, API: /docs)")
    console.print(f"data: {data}   logs: {logs}   modules connect to tcp://<this host>:{ingest_port}")
    for name, token in tokens.items():
        console.print(f"operator token for {name}: {token}")
    console.print("stop with Ctrl-C")
    try:
        run_server(data, host, port, events, tokens)
    finally:
        stop_children(children)


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
