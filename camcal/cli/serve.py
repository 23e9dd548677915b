"""``camcal serve``: the dashboard and the API. Exit status 0 when stopped, 1 after a failure,
3 when it could not start (port in use: the message says who holds it)."""

from __future__ import annotations

import signal
import socket
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from camcal.cli.common import DataOption, DbUrlOption, console, fail
from camcal.cli.config import settings_or_fail
from camcal.cli.credentials import operator_tokens
from camcal.core import runfile, supervise
from camcal.core.logs import configure_logging

if TYPE_CHECKING:
    from camcal.core.settings import Settings


def register(app: typer.Typer) -> None:
    app.command("serve")(serve)


class HttpServer:
    """The dashboard and API (uvicorn) in a thread of this process, on a socket bound beforehand.

    Binding first (`bind_http`) makes a taken port one clear error before
    anything runs; running in a thread leaves the main thread to handle
    signals and, in ``camcal up``, to watch the other parts.
    """

    def __init__(
        self,
        settings: Settings,
        tokens: dict[str, str],
        events: str | None,
        simulation_speed: float | None = None,
    ) -> None:
        import ssl

        import uvicorn

        from camcal.cli.dive import dive_rules
        from camcal.core.eventport import port_keys, use_curve
        from camcal.core.settings import endpoint_list
        from server.app import create_app
        from server.settings import ServerSettings
        from storage.store import Store

        server_settings = ServerSettings(
            data_dir=settings.data_dir,
            db_url=settings.database_url,
            events=events,
            operator_tokens=tokens,
            linear_range=settings.linear_range,
            station_depth_m=settings.station_depth_m,
            max_body_bytes=int(settings.http_max_body_mb * 1024 * 1024),
            max_websockets_per_client=settings.http_max_connections_per_client,
            max_requests_per_client=2 * settings.http_max_connections_per_client,
            simulation_speed=simulation_speed,
            trusted_proxies=tuple(settings.http_trusted_proxies),
            keys_dir=settings.keys_path(),
            events_curve=settings.events_curve,
            dive_rules=dive_rules(settings),
        )
        for endpoint in endpoint_list(events):  # an events port beyond loopback needs the ship's keys
            if use_curve(endpoint, settings.events_curve):
                port_keys(endpoint, settings.keys_path())
        # Opened here, not in the app's start-up: a database that cannot be opened is one line
        # (`storage.store.StoreUnavailable`) before anything runs, not uvicorn's traceback.
        self.store = Store.open(
            settings.data_dir, settings.database_url, run_migrations=server_settings.run_migrations
        )
        app = create_app(server_settings, store=self.store)
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
            timeout_graceful_shutdown=3,  # open WebSockets (browsers) do not hold up a stop
            ws_max_size=64 * 1024,  # a browser sends a few small requests; nothing needs more
            ssl_certfile=str(tls[0]) if tls else None,
            ssl_keyfile=str(tls[1]) if tls else None,
            # uvicorn would believe X-Forwarded-For from 127.0.0.1 (anyone on the ship's computer could
            # then pose as any address): the app's guard reads it from the configured proxies only.
            proxy_headers=False,
        )
        self.server = uvicorn.Server(config)
        host = {"0.0.0.0": "127.0.0.1", "::": "::1"}.get(settings.http_host, settings.http_host)
        self.url = (
            f"{'https' if tls else 'http'}://{f'[{host}]' if ':' in host else host}:{settings.http_port}"
        )
        # The health probe talks to this very server: its own certificate need not be checked.
        self._probe_tls = ssl._create_unverified_context() if tls else None
        self.error: BaseException | None = None
        self._thread: threading.Thread | None = None

    def start(self, sock: socket.socket) -> None:
        def run() -> None:
            try:
                self.server.run(sockets=[sock])
            except BaseException as exc:  # uvicorn exits (SystemExit) when the app's startup fails
                self.error = exc

        self._thread = threading.Thread(target=run, name="http", daemon=True)
        self._thread.start()

    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def wait_healthy(self, timeout_s: float, stop: threading.Event | None = None) -> None:
        """Wait until ``/healthz`` answers 200; `RuntimeError` if the server ends or stays silent."""
        import urllib.request

        end = time.monotonic() + timeout_s
        while not (stop is not None and stop.is_set()):
            if not self.alive():
                raise RuntimeError(f"the dashboard stopped while starting ({self.error!r}); see the log")
            if self.server.started:
                try:
                    with urllib.request.urlopen(
                        self.url + "/healthz", timeout=2, context=self._probe_tls
                    ) as r:
                        if r.status == 200:
                            return
                except OSError:
                    pass
            if time.monotonic() > end:
                raise RuntimeError(f"the dashboard did not answer {self.url}/healthz within {timeout_s:g} s")
            time.sleep(0.1)

    def stop(self, timeout_s: float = 5.0) -> None:
        self.server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout_s)
        self.store.close()


def bind_http(settings: Settings, setting: str = "--port (CAMCAL_HTTP_PORT)") -> socket.socket:
    """The dashboard's socket, bound; a taken port exits with status 3 and says who holds it."""
    try:
        return supervise.bind_tcp(settings.http_host, settings.http_port, part="dashboard", setting=setting)
    except supervise.PortInUse as exc:
        raise fail(str(exc), code=supervise.EXIT_NOT_STARTED) from None
    except OSError as exc:
        raise fail(str(exc), code=supervise.EXIT_NOT_STARTED) from None


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


def stop_signals() -> threading.Event:
    """An event set by SIGTERM (docker stop, systemd) or SIGINT (Ctrl-C): the main thread stops in order."""
    stop = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    return stop


def serve(
    data: DataOption = None,
    host: Annotated[
        str | None, typer.Option(help="Address; 0.0.0.0 for the ship's network [CAMCAL_HTTP_HOST].")
    ] = None,
    port: Annotated[int | None, typer.Option(help="HTTP port [CAMCAL_HTTP_PORT].")] = None,
    events: Annotated[
        str | None, typer.Option(help="The ingest's events; 'none' for review only [CAMCAL_EVENTS_CONNECT].")
    ] = None,
    db_url: DbUrlOption = None,
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
    sock = bind_http(s)
    stop = stop_signals()
    from camcal.core.eventport import EventPortError
    from storage.store import StoreUnavailable

    try:
        http = HttpServer(s, tokens, None if s.events_connect == "none" else s.events_connect)
    except (StoreUnavailable, EventPortError) as exc:
        sock.close()
        raise fail(str(exc), code=supervise.EXIT_NOT_STARTED) from None
    http.start(sock)
    try:
        http.wait_healthy(30.0, stop)
    except RuntimeError as exc:
        http.stop()
        raise fail(str(exc), code=supervise.EXIT_NOT_STARTED) from None
    console.print(f"camcal server: {http.url}  (API docs at /docs; data {s.data_dir})")
    supervise.notify_ready(f"dashboard on {http.url}", url=http.url)
    run_file = runfile.write(
        s.data_dir,
        "serve",
        {
            "http_host": s.http_host,
            "http_port": s.http_port,
            "events_connect": s.events_connect,
            "operators": sorted(tokens),  # their names: a token is never written down
        },
    )  # what `camcal doctor` checks
    while not stop.wait(0.5) and http.alive():
        pass
    runfile.remove(run_file)
    http.stop()
    if not stop.is_set():
        raise fail(f"the dashboard stopped by itself ({http.error!r}); see the log above", code=1)
