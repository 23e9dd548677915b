"""``camcal doctor``: check a deployment and say what to fix."""

from __future__ import annotations

import json
import shutil
import sys
import time
from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.table import Table
from rich.text import Text

from camcal.cli.common import DataOption, console, fail
from camcal.cli.config import settings_or_fail
from camcal.core.events import Event

if TYPE_CHECKING:
    from camcal.core.settings import Settings

OK, WARN, FAIL = "ok", "warn", "FAIL"


def register(app: typer.Typer) -> None:
    app.command("doctor")(doctor)


def _port_of(endpoint: str) -> tuple[str, int] | None:
    if not endpoint.startswith("tcp://") or ":" not in endpoint[6:]:
        return None
    host, port = endpoint[6:].rsplit(":", 1)
    try:
        return ("127.0.0.1" if host in ("*", "0.0.0.0") else host), int(port)
    except ValueError:
        return None


def check_ingest_port(s: Settings) -> list[tuple[str, str, str]]:
    """Whether something listens on the ingest's port, read from /proc/net/tcp: never by connecting
    (a connection without the link's handshake is what the ingest counts, and the deck sees, as a
    refused connection)."""
    from camcal.core import procinfo

    port = _port_of(s.ingest_bind)
    if port is None:
        return []
    if not procinfo.PROC.is_dir():
        return [("ingest port", OK, f"{port[1]} not looked at (no /proc here): the heartbeat below tells")]
    if not procinfo.port_uses(port[1]):
        return [("ingest port", FAIL, f"nothing listens on {port[1]}: start `camcal ingest`")]
    holder = procinfo.describe_holder(port[1])
    return [("ingest port", OK, f"{port[1]} is listened on" + (f" by {holder}" if holder else ""))]


def check_data(s: Settings) -> list[tuple[str, str, str]]:
    out = []
    d = s.data_dir
    if not d.exists():
        return [("data folder", FAIL, f"{d} does not exist: create it, or run `camcal up --data {d}`")]
    probe = d / ".doctor-probe"
    try:
        probe.write_bytes(b"x")
        probe.unlink()
        out.append(("data folder", OK, f"{d} is writable"))
    except OSError as exc:
        out.append(("data folder", FAIL, f"{d} is not writable ({exc.strerror}): fix its permissions"))
    free = shutil.disk_usage(d).free / 1e9
    limit = s.alarms.disk_min_free_gb
    status = OK if free >= 2 * limit else (WARN if free >= limit else FAIL)
    out.append(
        (
            "disk",
            status,
            f"{free:.1f} GB free (alarm below {limit:g} GB)"
            + ("" if status == OK else "; export and delete old dives or set CAMCAL_RETENTION_DAYS"),
        )
    )
    return out


def check_database(s: Settings) -> list[tuple[str, str, str]]:
    from storage.db import DataPaths, current_revision, head_revision, make_engine

    url = s.database_url or DataPaths(s.data_dir).sqlite_url()
    try:
        engine = make_engine(url)
        rev = current_revision(engine)
        engine.dispose()
    except Exception as exc:
        return [("database", FAIL, f"cannot connect to {url.split('@')[-1]}: {str(exc).splitlines()[0]}")]
    head = head_revision()
    if rev is None:
        return [("database", WARN, "empty: the ingest creates the tables when it starts (`camcal ingest`)")]
    if rev != head:
        return [
            (
                "database",
                FAIL,
                f"schema at {rev}, this camcal expects {head}: start `camcal ingest` to migrate",
            )
        ]
    return [("database", OK, f"reachable, schema {rev}")]


def check_ingest(s: Settings, wait_s: float) -> tuple[list[tuple[str, str, str]], dict[str, Any] | None]:
    import zmq

    from camcal.core.eventport import EventPortError, subscriber
    from camcal.core.settings import endpoint_list

    out = check_ingest_port(s)
    health = None
    ctx: Any = zmq.Context.instance()
    subs: list[Any] = []
    try:  # several ingests: any one's heartbeat will do; beyond loopback with the ship's keys
        for endpoint in endpoint_list(s.events_connect):
            subs.append(
                subscriber(ctx, endpoint, keys_dir=s.keys_path(), curve=s.events_curve, topics=[b"health"])
            )
        poller = zmq.Poller()
        for sub in subs:
            poller.register(sub, zmq.POLLIN)
        ready = poller.poll(int(wait_s * 1000))
        if ready:
            _, body = ready[0][0].recv_multipart()
            health = Event.from_json(body).payload
    except EventPortError as exc:
        out.append(("ingest events", FAIL, str(exc)))
        return out, None
    finally:
        for sub in subs:
            sub.close(0)
    if health is None:
        out.append(
            (
                "ingest events",
                FAIL,
                f"no heartbeat on {s.events_connect} within {wait_s:g} s: "
                "is the ingest running, and CAMCAL_EVENTS_CONNECT pointing at its --events? (An "
                "ingest publishing beyond loopback speaks CURVE: reach it by its network address or "
                "set CAMCAL_EVENTS_CURVE=true)",
            )
        )
    else:
        q = health.get("queues", {})
        out.append(("ingest events", OK, f"heartbeat received; queues {q}"))
        restarts = (health.get("counters") or {}).get("analysis_restarts", 0)
        if health.get("analysis_ready") is False or restarts:
            state = "starting" if health.get("analysis_ready") is False else "running"
            out.append(
                (
                    "ingest analysis",
                    WARN,
                    f"analysis processes {state}; replaced {restarts} time(s) after one died: if this "
                    "repeats, look for the OOM killer (`dmesg`); frames are kept and analysed again",
                )
            )
    return out, health


def check_link(s: Settings, health: dict[str, Any] | None) -> list[tuple[str, str, str]]:
    """The module link's security: keys, or a plaintext link (a warning), and refused connections."""
    from camcal.core.wire.keys import list_keys

    plaintext = s.link_plaintext or (health or {}).get("link_security") == "plaintext"
    if plaintext:
        out = [
            (
                "module link",
                WARN,
                "PLAINTEXT: no encryption, and anyone on the ship's network can claim any module id. "
                "For a lab bench only: create keys with `camcal keys create A B` and unset "
                "CAMCAL_LINK_PLAINTEXT",
            )
        ]
    else:
        keys = list_keys(s.keys_path())
        ship = [k for k in keys if k.owner == "ship" and k.has_secret]
        modules = sorted(k.owner for k in keys if k.owner != "ship")
        if not ship:
            fix = f"no ship key pair in {s.keys_path()}: run `camcal keys create A B`"
            out = [("module link", FAIL, fix)]
        else:
            which = ", ".join(modules) or "none yet: `camcal keys create ID`"
            out = [("module link", OK, f"CURVE; keys in {s.keys_path()}; modules let in: {which}")]
    refused = (health or {}).get("refused_connections") or {}
    if refused.get("last_minute"):
        src = (refused.get("sources") or [{}])[0]
        out.append(
            (
                "refused connections",
                WARN,
                f"{refused['last_minute']} in the last minute; newest: {src.get('reason')} from "
                f"{src.get('address') or 'an unknown address'} {src.get('key') or ''}".rstrip(),
            )
        )
    return out


def check_modules(s: Settings, health: dict[str, Any] | None) -> list[tuple[str, str, str]]:
    out = []
    live = (health or {}).get("modules", {})
    for m in s.modules:
        h = live.get(m.id)
        if health is None:
            out.append((f"module {m.id}", WARN, "unknown: no ingest heartbeat"))
            continue
        if h is None:
            out.append(
                (
                    f"module {m.id}",
                    FAIL,
                    "never connected to this ingest: check its --connect address "
                    f"({s.ingest_bind}), the fibre link and its power",
                )
            )
            continue
        if h["link"] != "up":
            out.append((f"module {m.id}", FAIL, f"link down, last packet {h['last_packet_age_s']} s ago"))
            continue
        off = h.get("clock_offset_s")
        if off is not None and abs(off) > 2.0:
            side = "ahead of" if off > 0 else "behind"
            out.append(
                (
                    f"module {m.id}",
                    WARN,
                    f"clock {abs(off):.1f} s {side} the ship: sync it (NTP over the fibre)",
                )
            )
        else:
            extra = f", clock offset {off:+.2f} s" if off is not None else ""
            out.append((f"module {m.id}", OK, f"link up, {h['frames_per_s']} frames/s{extra}"))
        if h.get("card_skipped"):
            out.append(
                (
                    f"module {m.id}",
                    WARN,
                    f"its SD card could not keep {h['card_skipped']} frame(s) or sensor message(s) this "
                    "boot (full?): free or swap the card at the next recovery",
                )
            )
        for key, what in (("capture_errors", "camera captures"), ("sensor_errors", "sensor reads")):
            if h.get(key):
                out.append(
                    (
                        f"module {m.id}",
                        WARN,
                        f"{h[key]} {what} failed this boot (the module retries them): check the "
                        "module's log and its cables",
                    )
                )
    return out


def check_http(s: Settings) -> list[tuple[str, str, str]]:
    import urllib.error
    import urllib.request

    host = "127.0.0.1" if s.http_host in ("0.0.0.0", "::") else s.http_host
    url = f"http://{host}:{s.http_port}/api/health"
    try:
        with urllib.request.urlopen(url, timeout=3) as r:
            body = json.loads(r.read())
        return [("dashboard", OK, f"{url} answers ({body.get('status')})")]
    except (urllib.error.URLError, OSError, ValueError) as exc:
        return [
            (
                "dashboard",
                FAIL,
                f"{url} does not answer ({getattr(exc, 'reason', exc)}): start `camcal serve`",
            )
        ]


def check_processes(s: Settings) -> list[tuple[str, str, str]]:
    """camcal's processes on this machine and the ports they hold; those left behind by this
    installation are a warning (with how to stop them). Those of another installation (another
    venv: a colleague's checkout, another deployment) are listed as such and never to be killed
    from here: only one holding a port this deployment uses is a warning."""
    from camcal.core import procinfo

    wanted = {p for p in (_port_of(s.ingest_bind), _port_of(s.events_connect.split(",")[0])) if p}
    configured = {port for _, port in wanted} | {s.http_port}
    ours = Path(sys.prefix).resolve()
    rows = []
    others: dict[Path, list[str]] = {}  # another installation's processes: counted, never to be killed here
    for c in procinfo.camcal_processes():
        p = c.process
        age = procinfo.age_s(p)
        ports = f"; holds port {', '.join(str(n) for n in p.ports)}" if p.ports else ""
        clash = sorted(set(p.ports) & configured)
        running = f", running {age / 60:.0f} min" if age is not None else ""
        command = f": {procinfo.short(c.args, 70)}" if c.args else ""
        detail = f"{c.kind} (parent {p.ppid}{running}){ports}{command}"
        held = ", ".join(map(str, clash))
        if c.installation is not None and c.installation != ours:
            if clash:
                other = f"of another camcal installation ({c.installation})"
                fix = f"; it holds port {held}, which this deployment uses: ask its owner, or use other ports"
                rows.append((f"process {p.pid}", WARN, f"{other}{fix}. {detail}"))
            else:
                others.setdefault(c.installation, []).append(c.kind)
        elif c.leftover:
            fix = f"; it holds the configured port {held}" if clash else ""
            rows.append(
                (f"process {p.pid}", WARN, f"left behind: {c.leftover}{fix}; stop it: kill {p.pid}. {detail}")
            )
        else:
            rows.append((f"process {p.pid}", OK, detail))
    for where, kinds in sorted(others.items()):
        count = ", ".join(f"{n} {k}" for k, n in sorted(Counter(kinds).items()))
        rows.append(
            ("other camcal", OK, f"{count} of another installation ({where}): not this one's to stop")
        )
    if not rows:
        rows.append(("processes", OK, "no camcal process runs on this machine"))
    return rows


def running_settings(s: Settings) -> tuple[Settings, list[tuple[str, str, str]]]:
    """The settings of the system that runs on this data folder (its run files, `camcal.core.runfile`),
    over ``s``: a `camcal up --port 8123 --ingest-port 5565` is checked on its own ports, whatever the
    environment says. With the row that says which services run and what differs from ``s``."""
    from camcal.core import runfile

    services = runfile.running(s.data_dir)
    if not services:
        return s, [("running system", OK, f"no camcal service has announced itself in {s.data_dir}: "
                    "checked with the settings above")]  # fmt: skip
    update: dict[str, Any] = {}
    ingests = [r for r in services if r.service == "ingest"]
    for r in services:  # oldest first; `camcal up` says it all, its own ingest the same again
        st = r.settings
        if "http_port" in st:
            update["http_host"], update["http_port"] = st["http_host"], int(st["http_port"])
        if st.get("events_connect") and st["events_connect"] != "none":
            update["events_connect"] = st["events_connect"]
    up = [r for r in services if r.service == "up"]
    if up:
        update["ingest_bind"] = up[-1].settings["ingest_bind"]
        update["events_connect"] = up[-1].settings["events_connect"]
    elif ingests:
        update["ingest_bind"] = ingests[-1].settings["ingest_bind"]
        if "events_connect" not in update:
            update["events_connect"] = ",".join(
                _local(r.settings["events_bind"]) for r in ingests if r.settings.get("events_bind")
            )
            if any(r.settings.get("events_curve") for r in ingests):  # reached on 127.0.0.1: say CURVE
                update["events_curve"] = True
    differs = [
        f"{key} {update[key]} (your settings: {getattr(s, key)})"
        for key in ("http_port", "ingest_bind", "events_connect")
        if key in update and str(update[key]) != str(getattr(s, key))
    ]
    since = ", ".join(
        f"camcal {r.service} (pid {r.pid}, since {_hms(r.started_unix_s)} UTC)" for r in services
    )
    note = f"; checked on its own settings: {'; '.join(differs)}" if differs else ""
    return s.model_copy(update=update), [("running system", OK, f"{since} in {s.data_dir}{note}")]


def running_operators(s: Settings) -> list[str]:
    """The operators (names, never tokens) the running dashboard lets in, as its run file says."""
    from camcal.core import runfile

    names = [n for r in runfile.running(s.data_dir) for n in r.settings.get("operators") or []]
    return sorted(set(names))


def _hms(unix_s: float) -> str:
    return time.strftime("%H:%M:%S", time.gmtime(unix_s))


def _local(endpoint: str) -> str:
    """Where to connect to a bound endpoint from this machine (``tcp://*:5556`` -> ``tcp://127.0.0.1:5556``)."""
    for anywhere in ("tcp://*:", "tcp://0.0.0.0:"):
        if endpoint.startswith(anywhere):
            return "tcp://127.0.0.1:" + endpoint[len(anywhere) :]
    return endpoint


def doctor(
    data: DataOption = None,
    config: Annotated[Path | None, typer.Option(help="A TOML configuration file [CAMCAL_CONFIG].")] = None,
    wait: Annotated[float, typer.Option(help="Seconds to wait for the ingest's heartbeat.")] = 3.0,
    check: Annotated[
        list[str] | None,
        typer.Option(
            help="Only these checks (repeat): data, database, ingest, modules, dashboard, processes."
        ),
    ] = None,
) -> None:
    """Check the configuration, data folder, disk, database, ingest, modules, dashboard, and list camcal's
    processes (with the ports they hold; those left behind by a camcal that ended are a warning).

    A camcal running on the data folder is checked on its own settings (the ports it was started
    with, from its run file in DATA/run/), and only looked at: nothing connects to the modules' port
    (the ingest would count a refused connection), nothing is stopped."""
    s = settings_or_fail(config, data_dir=data)
    checks = ("data", "database", "ingest", "modules", "dashboard", "processes")
    wanted = set(check or checks)
    unknown = wanted - set(checks)
    if unknown:
        raise fail(f"unknown check(s): {', '.join(sorted(unknown))} (the checks: {', '.join(checks)})")
    s, running = running_settings(s)
    rows = [("configuration", OK, "loaded"), *running]
    if "data" in wanted:
        rows += check_data(s)
    if "database" in wanted:
        rows += check_database(s)
    health = None
    if wanted & {"ingest", "modules"}:
        ingest_rows, health = check_ingest(s, wait)
        rows += ingest_rows + check_link(s, health) if "ingest" in wanted else []
    if "modules" in wanted:
        rows += check_modules(s, health)
    if "dashboard" in wanted:
        rows += check_http(s)
    if "processes" in wanted:
        rows += check_processes(s)
    operators = running_operators(s)
    if operators:
        rows.append(("operator tokens", OK, f"the running dashboard lets in: {', '.join(operators)}"))
    elif not s.operator_tokens and check is None:
        rows.append(
            ("operator tokens", WARN, "none configured: nobody can send commands (CAMCAL_OPERATOR_TOKENS)")
        )
    table = Table(title="camcal doctor", title_justify="left")
    for col in ("check", "status", "detail / what to do"):
        table.add_column(col)
    colour = {OK: "green", WARN: "yellow", FAIL: "bold red"}
    for name, status, detail in rows:
        table.add_row(name, Text(status, style=colour[status]), detail)
    console.print(table)
    if any(st == FAIL for _, st, _ in rows):
        raise typer.Exit(1)
