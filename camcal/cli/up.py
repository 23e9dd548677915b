"""``camcal up``: the whole system on one machine, started and ended as one.

The ingest and the simulated modules run as children (`camcal.core.supervise`):
each ends with this process however it ends. ``camcal is up`` is printed
only once every part reports healthy: the ingest bound (its ready report)
and publishing (a health event), the dashboard answering ``/healthz``, and
each simulated module linked to *this* ingest (its health lists the link up).

Exit status: 0 stopped by SIGINT/SIGTERM; 1 a part failed while running (all
stopped); 2 wrong option; 3 could not start (all stopped; the message names
the part, the port and the setting).
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from camcal.cli.common import console, err_console, fail, labelled
from camcal.cli.config import settings_or_fail
from camcal.cli.credentials import child_environment, ship_key, simulated_link, tokens_or_generated
from camcal.cli.dive import dive_for_start
from camcal.cli.serve import HttpServer, bind_http, stop_signals
from camcal.core import procinfo, runfile, supervise
from camcal.core.logs import configure_logging

if TYPE_CHECKING:
    from camcal.core.settings import Settings

MODULES = ("A", "B")
#: Where the simulated dive begins: on deck (the real-time descent first), at the first test stop, on station.
BEGINNINGS = ("deck", "first-stop", "station")
INGEST_READY_S = 20.0
HTTP_READY_S = 15.0
MODULES_LINKED_S = 20.0
STOP_S = 3.5  # modules, then the ingest: what is left after this is killed (their data is safe on disk)
#: On a busy machine the parts get STOP_S stretched by how busy it is (`stop_budget_s`), at most this:
#: under systemd's TimeoutStopSec (20 s, deploy/camcal.service).
STOP_MAX_S = 15.0


def register(app: typer.Typer) -> None:
    app.command("up")(up)


class Interrupted(Exception):
    """SIGINT or SIGTERM while starting."""


def up(
    data: Annotated[
        Path | None,
        typer.Option(help="Data folder; an open dive there still in the water is continued."),
    ] = None,
    port: Annotated[int | None, typer.Option(help="Dashboard port [CAMCAL_HTTP_PORT].")] = None,
    host: Annotated[str | None, typer.Option(help="Dashboard address [CAMCAL_HTTP_HOST].")] = None,
    ingest_port: Annotated[int, typer.Option(help="Port modules connect to.")] = 5555,
    ingest_host: Annotated[
        str, typer.Option(help="Address the ingest listens on; 0.0.0.0 for modules on the ship's network.")
    ] = "127.0.0.1",
    events_port: Annotated[int, typer.Option(help="Port of the ingest's event publisher.")] = 5556,
    simulate: Annotated[bool, typer.Option(help="Run two simulated modules (A and B).")] = True,
    speed: Annotated[float, typer.Option(help="Speed of the simulated dive.")] = 10.0,
    frame_scale: Annotated[float, typer.Option(help="Simulated sensor scale (1 = 5 MP).")] = 0.5,
    schedule: Annotated[str, typer.Option(help="Schedule of the simulated modules.")] = "trex-subsampled",
    seed: Annotated[int, typer.Option(help="Seed of the simulated dive.")] = 0,
    begin: Annotated[
        str,
        typer.Option(
            help="Where the simulated dive begins: first-stop (frames at once), station, or deck "
            "(on deck, then the descent in real time: frames after minutes)."
        ),
    ] = "first-stop",
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
        list[str] | None,
        typer.Option(help="NAME=TOKEN of an operator (repeat); shown by ps: use CAMCAL_OPERATOR_TOKENS."),
    ] = None,
    config: Annotated[Path | None, typer.Option(help="A TOML configuration file [CAMCAL_CONFIG].")] = None,
) -> None:
    """Start the whole system: ingest, two simulated modules on a simulated dive, and the dashboard."""
    s = settings_or_fail(config, data_dir=data, http_host=host, http_port=port)
    configure_logging(s.log_level, s.log_format)
    if begin not in BEGINNINGS:
        raise fail(f"--begin: one of {', '.join(BEGINNINGS)}, got {begin!r}")
    profile = _dive_profile(deck_s, winch_m_per_s, test_stop_s, station_s) if simulate else None
    tokens, generated = tokens_or_generated(operator_token, s)
    ingest_bind = f"tcp://{ingest_host}:{ingest_port}"
    connect = f"tcp://{'127.0.0.1' if ingest_host in ('0.0.0.0', '*') else ingest_host}:{ingest_port}"
    events = f"tcp://127.0.0.1:{events_port}"
    # Every port first: a taken one is one line naming who holds it, before anything starts.
    try:
        for endpoint, part, setting in (
            (ingest_bind, "ingest", port_setting("--ingest-port")),
            (events, "ingest's event publisher", port_setting("--events-port")),
        ):
            supervise.check_endpoint(endpoint, part=part, setting=setting)
    except supervise.PortInUse as exc:
        raise fail(str(exc), code=supervise.EXIT_NOT_STARTED) from None
    http_sock = bind_http(s, port_setting("--port", "CAMCAL_HTTP_PORT"))
    data_dir = s.data_dir
    logs = data_dir / "logs"
    try:
        logs.mkdir(parents=True, exist_ok=True)
        dive, dive_line = dive_for_start(s)  # creates or migrates the database before anyone uses it
    except Exception as exc:
        http_sock.close()
        raise fail(f"cannot open the store in {data_dir}: {exc}", code=supervise.EXIT_NOT_STARTED) from None
    # The simulated modules' link keys (made on first start) and the dive they are started for: a
    # module refuses an ingest of another dive.
    if profile is None:
        ship_key(s)  # real modules: their keys come from `camcal keys create`
    link = [*(simulated_link(s, list(MODULES)) if profile is not None else []), "--dive", dive]
    if profile is not None and s.station_depth_m is None:  # the simulated dive's plan
        s = s.model_copy(update={"station_depth_m": profile.station_depth_m})

    stop = stop_signals()
    sup = supervise.Supervisor()
    http: HttpServer | None = None
    modules: list[supervise.Child] = []
    code = supervise.EXIT_OK
    parts = "the ingest, the dashboard" + (f" and modules {' and '.join(MODULES)}" if profile else "")
    console.print(f"starting {parts} (data in {data_dir}) ...")
    console.print(dive_line)
    run_file = runfile.write(
        data_dir,
        "up",
        {
            "http_host": s.http_host,
            "http_port": s.http_port,
            "ingest_bind": ingest_bind,
            "modules_connect": connect,
            "events_bind": events,
            "events_connect": events,
            "operators": sorted(tokens),  # their names: a token is never written down
        },
    )  # what `camcal doctor` checks: these options, not the defaults
    try:
        t_spawn = time.monotonic()
        ingest = sup.spawn(
            "ingest",
            ingest_args(data_dir, ingest_bind, events, dive),
            logs / "ingest.log",
            child_environment(),
        )
        # the dashboard starts while the ingest does; it says when the modules are simulated
        http = HttpServer(s, tokens, events, simulation_speed=speed if profile is not None else None)
        http.start(http_sock)
        if sup.wait_ready(ingest, INGEST_READY_S, stop) is None:
            raise Interrupted
        if profile is not None:
            begin_s = _begin_s(profile, begin)
            # Both modules begin the dive together, at `begin_s` once they have started: as long, about,
            # as the ingest took (the same imports; a busy machine shows there). Until then they are
            # still on the way down, so a short test stop is not half over before their first frame.
            epoch = time.time() + min(max(time.monotonic() - t_spawn, 1.0), 10.0)
            for m in MODULES:
                args = module_args(
                    m, connect, data_dir / f"outbox-{m}", speed=speed, frame_scale=frame_scale,
                    schedule=schedule, seed=seed, epoch=epoch, begin_s=begin_s, deck_s=deck_s,
                    winch_m_per_s=winch_m_per_s, test_stop_s=test_stop_s, station_s=station_s,
                )  # fmt: skip
                modules.append(
                    sup.spawn(f"module {m}", [*args, *link], logs / f"module-{m}.log", child_environment())
                )
        http.wait_healthy(HTTP_READY_S, stop)
        wait_linked(events, MODULES if modules else (), sup, stop, MODULES_LINKED_S)
        if stop.is_set():
            raise Interrupted
        _print_up(s, data_dir, logs, ingest_host, ingest_port, tokens if generated else {})
        supervise.notify_ready(f"dashboard http://{s.http_host}:{s.http_port}")
        code = watch(sup, http, stop)
    except Interrupted:
        console.print("stopping before camcal was up (interrupted)")
    except (supervise.ChildFailed, RuntimeError) as exc:
        err_console.print(labelled("error:", "bold red", f"camcal could not start: {exc}"), highlight=False)
        code = supervise.EXIT_NOT_STARTED
    finally:
        supervise.sd_notify("STOPPING=1")
        if http is not None:
            http.server.should_exit = True  # the dashboard winds down while the children stop
        else:
            http_sock.close()
        t_stop, budget_s = time.monotonic(), stop_budget_s()
        sup.stop([modules, [c for c in sup.children if c not in modules]], budget_s)
        if http is not None:  # whatever is left of it ends with this process
            http.stop(max(0.1, budget_s + 1.0 - (time.monotonic() - t_stop)))
        runfile.remove(run_file)
        console.print("stopped: " + ", ".join(f"{c.name} ({c.proc.returncode})" for c in sup.children))
    raise typer.Exit(code)


#: Set by `make run`: the make variable of each port option ("--port=PORT --ingest-port=INGEST_PORT ...").
PORT_VARIABLES = "CAMCAL_PORT_VARIABLES"


def port_setting(option: str, env: str | None = None) -> str:
    """How to choose another port: the option, its environment variable, and under `make run` the
    make variable that sets it (``--ingest-port (make run INGEST_PORT=...)``)."""
    words = dict(w.partition("=")[::2] for w in os.environ.get(PORT_VARIABLES, "").split())
    also = [env] if env else []
    if words.get(option):
        also.append(f"make run {words[option]}=...")
    return f"{option} ({', '.join(also)})" if also else option


def stop_budget_s() -> float:
    """How long the parts get to stop in order before what is left is killed: `STOP_S` on an idle
    machine; on a busy one as many times longer as processes wait for each core (an ingest that
    flushes in 3 s alone was killed mid-flush beside two CPU-bound jobs), at most `STOP_MAX_S`."""
    return min(STOP_MAX_S, STOP_S * procinfo.busy_factor())


def ingest_args(data_dir: Path, bind: str, events: str, dive: str) -> list[str]:
    """The ``camcal`` arguments of the ingest ``camcal up`` runs."""
    return ["ingest", "--data", str(data_dir), "--bind", bind, "--events", events, "--dive", dive]


def module_args(
    module: str,
    connect: str,
    outbox: Path,
    *,
    speed: float,
    frame_scale: float,
    schedule: str,
    seed: int,
    epoch: float,
    begin_s: float,
    deck_s: float,
    winch_m_per_s: float,
    test_stop_s: float,
    station_s: float,
) -> list[str]:
    """The ``camcal`` arguments of a simulated module: both share the dive (seed, epoch, profile)."""
    options = {
        "--camera": module,
        "--connect": connect,
        "--outbox": outbox,
        "--speed": speed,
        "--frame-scale": frame_scale,
        "--schedule": schedule,
        "--seed": seed,
        "--epoch": epoch,
        "--begin-s": begin_s,
        "--deck-s": deck_s,
        "--winch-m-per-s": winch_m_per_s,
        "--test-stop-s": test_stop_s,
        "--station-s": station_s,
    }
    return ["lrm", "simulate", *(str(x) for kv in options.items() for x in kv)]


def _dive_profile(deck_s: float, winch_m_per_s: float, test_stop_s: float, station_s: float) -> Any:
    from lrm.dive import DiveProfile

    try:
        return DiveProfile(
            deck_s=deck_s,
            descent_m_per_s=winch_m_per_s,
            ascent_m_per_s=winch_m_per_s,
            test_stop_s=test_stop_s,
            station_s=station_s,
        )
    except ValueError as exc:
        raise fail(str(exc)) from None


def _begin_s(profile: Any, begin: str) -> float:
    """Dive time of ``begin``: 0 on deck, else the start of the first test stop or of the station."""
    if begin == "deck":
        return 0.0
    phase = "station" if begin == "station" or not profile.test_stops_m else None
    phase = phase or profile.stop_phase(profile.test_stops_m[0])
    return float(profile.window(phase)[0])


def wait_linked(
    events: str, modules: tuple[str, ...], sup: supervise.Supervisor, stop: threading.Event, timeout_s: float
) -> dict[str, Any]:
    """The ingest's first health report (on its event publisher) listing every module's link up.

    Only this ingest can publish there (it bound the port), so a module listed
    up has handshaked with it. `ChildFailed` if a part ends or ``timeout_s`` passes.
    """
    import zmq

    ctx: Any = zmq.Context.instance()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"health")
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(events)
    end = time.monotonic() + timeout_s
    health: dict[str, Any] = {}
    try:
        while not stop.is_set():
            for child in sup.exited():
                raise supervise.ChildFailed(
                    f"{child.name} {child.describe_exit()} while starting; its log {child.log}:\n"
                    f"{child.log_tail()}"
                )
            if sub.poll(200):
                _, body = sub.recv_multipart()
                health = json.loads(body).get("payload", {})
                links = health.get("modules", {})
                if all(links.get(m, {}).get("link") == "up" for m in modules):
                    return health
            if time.monotonic() > end:
                raise supervise.ChildFailed(_not_linked(health, modules, sup, events, timeout_s))
        raise Interrupted
    finally:
        sub.close(0)


def _not_linked(
    health: dict[str, Any], modules: tuple[str, ...], sup: supervise.Supervisor, events: str, timeout_s: float
) -> str:
    if not health:
        return f"no health report from the ingest on {events} within {timeout_s:g} s"
    links = health.get("modules", {})
    logs = {c.name: c.log for c in sup.children}
    missing = [m for m in modules if links.get(m, {}).get("link") != "up"]
    return f"not linked to the ingest within {timeout_s:g} s: " + "; ".join(
        f"module {m} (link {links.get(m, {}).get('link', 'never seen')}; its log {logs.get(f'module {m}')})"
        for m in missing
    )


def watch(sup: supervise.Supervisor, http: HttpServer, stop: threading.Event) -> int:
    """Run until SIGINT/SIGTERM (0) or a part fails (1); a module that finished its dive is no failure.

    Under systemd with ``WatchdogSec=``, each round tells it that camcal up still watches its parts.
    """
    finished: set[str] = set()
    watchdog = bool(os.environ.get("WATCHDOG_USEC"))
    while not stop.wait(0.5):
        if watchdog:
            supervise.sd_notify("WATCHDOG=1")
        if not http.alive():
            err_console.print(
                labelled("error:", "bold red", f"the dashboard stopped ({http.error!r}); stopping camcal")
            )
            return supervise.EXIT_FAILED
        for child in sup.exited():
            if child.name.startswith("module") and child.proc.returncode == 0:
                if child.name not in finished:
                    finished.add(child.name)
                    console.print(f"{child.name} finished its dive (its log: {child.log})")
                continue
            err_console.print(
                labelled(
                    "error:",
                    "bold red",
                    f"the {child.name} {child.describe_exit()}; stopping camcal. "
                    f"Its log {child.log}:\n{child.log_tail()}",
                ),
                highlight=False,
            )
            return supervise.EXIT_FAILED
    return supervise.EXIT_OK


def _modules_connect(host: str, port: int) -> str:
    """Where modules connect, as the ingest listens: this machine only, or the ship's network."""
    if host in ("0.0.0.0", "*", "::"):
        return f"modules connect to tcp://<this host's address>:{port}"
    if host in ("127.0.0.1", "localhost", "::1"):
        return (
            f"modules on this machine connect to tcp://{host}:{port} "
            "(--ingest-host 0.0.0.0 for modules on the ship's network)"
        )
    return f"modules connect to tcp://{host}:{port}"


def _print_up(
    s: Settings, data_dir: Path, logs: Path, ingest_host: str, ingest_port: int, tokens: dict[str, str]
) -> None:
    console.print(
        labelled(
            "camcal is up:",
            "bold",
            f"dashboard http://{s.http_host}:{s.http_port}  (review: /review, API: /docs)",
        )
    )
    console.print(f"data: {data_dir}   logs: {logs}", highlight=False)
    console.print(_modules_connect(ingest_host, ingest_port), highlight=False, soft_wrap=True)
    for name, token in tokens.items():  # only a token camcal made up: a configured one is never shown
        console.print(f"operator token for {name}: {token}")
    console.print("stop with Ctrl-C")
