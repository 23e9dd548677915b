"""``camcal lrm``: run a module — simulated, or replaying a recorded frame set; its real camera's
commands (``run``, ``cameras``, ``snap``) are in `camcal.cli.lrm_camera`, ``doctor`` in
`camcal.cli.lrm_doctor`."""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from camcal.cli.common import console, fail, labelled
from camcal.cli.defaults import DATA_DIR

if TYPE_CHECKING:
    from camcal.core.schedule import Schedule

app = typer.Typer(
    help="Run a light receiver module: a real camera, simulated, or replaying a frame set.",
    no_args_is_help=True,
)


ConnectOption = Annotated[str, typer.Option(help="The ship's ingest: tcp://HOST:PORT.")]
KeysOption = Annotated[
    Path,
    typer.Option(
        envvar="CAMCAL_KEYS_DIR",
        help="Keys folder: ship.key and modules/<camera>.key_secret (`camcal keys create` on the ship).",
    ),
]
PlaintextOption = Annotated[
    bool,
    typer.Option(
        envvar="CAMCAL_LINK_PLAINTEXT",
        help="No keys, no encryption: only for a lab bench whose ingest allows it too.",
    ),
]
DiveOption = Annotated[
    str | None,
    typer.Option(
        envvar="CAMCAL_DIVE",
        help="The dive this module is started for: it refuses an ingest that records another.",
    ),
]
#: Exit status of a module that refused the ship it was pointed at (another dive, not a camcal ship).
REFUSED_EXIT = 3
#: How long a handshake may keep failing before a simulated or replaying module gives up.
REFUSAL_GRACE_S = 10.0


def link_keys(keys: Path, camera: str, plaintext: bool) -> Any:
    """The module's CURVE keys from ``keys``, or None for an explicitly plaintext link."""
    from camcal.core import wire

    if plaintext:
        console.print(
            labelled(
                "warning:", "yellow", "plaintext link: no encryption, no authentication (lab bench only)"
            )
        )
        return None
    try:
        return wire.module_keys(keys, camera)
    except wire.KeyFileError as exc:
        raise fail(str(exc)) from None


def refused(agent: Any) -> bool:
    """A simulated or replaying module stops when it refuses the ship for good (or for a while)."""
    r = agent.refusal
    return r is not None and (r.definitive or time.monotonic() - r.since_mono >= REFUSAL_GRACE_S)


def with_outbox(make: Callable[[], Any]) -> Any:
    """``make()`` (a module agent, which opens its outbox); an outbox it cannot write is a one-line
    error and exit status 3 (not started), not a traceback."""
    from camcal.core.supervise import EXIT_NOT_STARTED
    from lrm.outbox import OutboxUnavailable

    try:
        return make()
    except OutboxUnavailable as exc:
        raise fail(str(exc), code=EXIT_NOT_STARTED) from None


def register(parent: typer.Typer) -> None:
    from camcal.cli.lrm_conformance import lrm_conformance

    app.command("conformance")(lrm_conformance)
    parent.add_typer(app, name="lrm")


def load_schedule(name: str) -> Schedule:
    """A preset name or a JSON file with a schedule."""
    from camcal.core.schedule import Schedule, presets

    table = presets()
    if name in table:
        return table[name]
    path = Path(name)
    if path.is_file():
        try:
            return Schedule.model_validate_json(path.read_text())
        except ValueError as exc:
            raise fail(f"{path}: not a valid schedule: {str(exc).splitlines()[0]}") from None
    raise fail(f"--schedule: {name!r} is neither a preset ({', '.join(table)}) nor a schedule file")


def _run_module(agent: Any, finished: Callable[[], bool], *, stop_on_refusal: bool = True) -> None:
    """Run a started module agent until SIGTERM/SIGINT or ``finished()``; stop it and say what is left.

    Exit status 0 when stopped or finished, 1 when the agent stopped after a failure; with
    ``stop_on_refusal`` it also stops when the agent refuses the ship, and exits with
    `REFUSED_EXIT` and the reason.
    """
    failed = _run_until_signal(agent, lambda: finished() or (stop_on_refusal and refused(agent)))
    agent.stop()
    console.print(
        f"module {agent.config.module}: stopped; {agent.counters['frames_captured']} frames captured, "
        f"{agent.outbox.pending_count()} not yet acknowledged (kept in {agent.config.outbox})"
    )
    if stop_on_refusal and refused(agent):
        raise fail(f"module {agent.config.module}: {agent.refusal.message}", code=REFUSED_EXIT)
    if failed:
        raise fail(f"module {agent.config.module} stopped after a failure (see the log above)", code=1)


def _run_until_signal(agent: Any, finished: Callable[[], bool]) -> bool:
    """Wait for SIGTERM/SIGINT or ``finished()``; True if the agent stopped by itself (a failure).

    Under systemd (``Type=notify``) this loop tells it the module is ready once the agent runs, and,
    with ``WatchdogSec``, feeds the watchdog only while the agent works (`lrm.agent.Agent.alive`):
    a module whose threads hang is restarted. ``STATUS=`` says what it has done, for ``systemctl status``.
    """
    from camcal.core.supervise import sd_notify

    done = threading.Event()

    def on_signal(signum: int, _frame: object) -> None:
        done.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    watchdog_s = int(os.environ.get("WATCHDOG_USEC", "0") or 0) / 1e6
    sd_notify("READY=1\n" + _status(agent))
    last_ping = 0.0
    while not done.wait(min(0.5, watchdog_s / 4) if watchdog_s > 0 else 0.5):
        if agent.stopped:
            return True
        if finished():
            break
        now = time.monotonic()
        if watchdog_s > 0 and now - last_ping >= watchdog_s / 4 and agent.alive():
            sd_notify("WATCHDOG=1\n" + _status(agent))
            last_ping = now
    sd_notify("STOPPING=1")
    return False


def _status(agent: Any) -> str:
    """systemd's one-line STATUS of a module: frames taken, waiting on the card, link and camera."""
    link = "linked" if agent.linked.is_set() else "looking for the ship"
    camera = agent.device_errors.get("camera")
    return (
        f"STATUS={agent.counters['frames_captured']} frames, {agent.outbox.pending_count()} not yet "
        f"acknowledged, {link}" + (f"; camera: {camera[:120]}" if camera else "")
    )


@app.command("simulate")
def simulate(
    camera: Annotated[str, typer.Option(help="Module / camera id: A (21.56 m) or B (41.62 m).")] = "A",
    connect: ConnectOption = "tcp://127.0.0.1:5555",
    outbox: Annotated[
        Path | None, typer.Option(help="SD-card outbox folder (default lrm-<camera>-outbox).")
    ] = None,
    speed: Annotated[float, typer.Option(help="Simulated seconds per real second.")] = 1.0,
    schedule: Annotated[str, typer.Option(help="Schedule preset or JSON file.")] = "trex",
    seed: Annotated[
        int, typer.Option(help="Seed of the simulated dive (use one seed for both modules).")
    ] = 0,
    frame_scale: Annotated[
        float, typer.Option(help="Sensor scale for fast runs (1 = 5 MP, 0.25 = 612x512).")
    ] = 1.0,
    station_s: Annotated[float, typer.Option(help="Time on station at 3420 m [s].")] = 1800.0,
    test_stop_s: Annotated[float, typer.Option(help="Time at each test stop (1200 m, 2021 m) [s].")] = 120.0,
    deck_s: Annotated[float, typer.Option(help="Time on deck before the descent [s].")] = 60.0,
    winch_m_per_s: Annotated[float, typer.Option(help="Descent and ascent speed [m/s].")] = 1.0,
    readout_s: Annotated[float, typer.Option(help="Camera readout and transfer time per frame [s].")] = 0.8,
    epoch: Annotated[
        float | None,
        typer.Option(help="Wall-clock UNIX time at which the simulation begins (shared by modules)."),
    ] = None,
    begin_s: Annotated[
        float,
        typer.Option(help="Dive time at which the simulation begins [s]; 0: on deck, before the descent."),
    ] = 0.0,
    drift: Annotated[
        float,
        typer.Option(
            help="How much the water changes on station: with --drift-shape sine the change of the "
            "coefficients from the station's start to its end; with bump the fall of λ_att at "
            "mid-station (0.3: 28 -> 19.6 -> 28 m at 460 nm)."
        ),
    ] = 0.04,
    drift_shape: Annotated[str, typer.Option(help="sine (a steady trend) or bump (down and back).")] = "sine",
    lem_dwell_s: Annotated[
        float, typer.Option(help="Seconds the LEM shows each wavelength (its timetable's block).")
    ] = 60.0,
    lem_settle_s: Annotated[
        float,
        typer.Option(
            help="Wait after each change of LEM colour before the first shot [s] (e.g. 0.45 on one "
            "module to interleave its frames with the other's)."
        ),
    ] = 0.0,
    sensor_rate_hz: Annotated[
        float, typer.Option(help="Housing sensor samples per simulated second (lower it at high --speed).")
    ] = 10.0,
    fsync: Annotated[bool, typer.Option(help="fsync every frame on the SD card (outbox).")] = True,
    tilt_scale: Annotated[float, typer.Option(help="Factor on this module's tilt (alarm tests).")] = 1.0,
    leak_at_s: Annotated[
        float | None, typer.Option(help="Dive time at which the housing starts leaking.")
    ] = None,
    exit_when_recovered: Annotated[
        bool, typer.Option(help="Exit once the dive is over and all is sent.")
    ] = True,
    clock_error_s: Annotated[
        float,
        typer.Option(
            help="A module clock this far off [s], in its stamps and messages (-1.8e9: a clock never "
            "set, reading 1970); the simulated world is not moved."
        ),
    ] = 0.0,
    dive: DiveOption = None,
    keys: KeysOption = Path(DATA_DIR) / "keys",
    plaintext: PlaintextOption = False,
    log_level: Annotated[str, typer.Option(help="debug, info, warning.")] = "info",
) -> None:
    """Run a simulated module through a whole T-REX dive and stream it to the ship.

    Exits with status 3 if the ship at --connect is not the right one (another dive, or
    not a camcal ingest)."""
    from lrm.agent import AgentConfig
    from lrm.clock import SimClock
    from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
    from lrm.simmodule import simulated_module

    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sched = load_schedule(schedule)
    module_keys = link_keys(keys, camera, plaintext)
    try:
        profile = DiveProfile(
            deck_s=deck_s,
            descent_m_per_s=winch_m_per_s,
            ascent_m_per_s=winch_m_per_s,
            test_stop_s=test_stop_s,
            station_s=station_s,
        )
        if not 0 <= begin_s < profile.duration_s:
            raise ValueError(f"--begin-s must be between 0 and the dive's {profile.duration_s:.0f} s")
        epoch_s = epoch if epoch is not None else time.time()
        # Dive time 0 lies begin_s before the epoch: at the epoch the dive is at begin_s, and the
        # simulated wall clock reads the real one (it runs `speed` times faster from there).
        start = datetime.fromtimestamp(epoch_s - begin_s, UTC)
        if drift_shape == "sine":
            column = WaterColumn.with_station_drift(profile, drift)
        elif drift_shape == "bump":
            column = WaterColumn.with_station_bump(profile, drift)
        else:
            raise ValueError(f"--drift-shape must be sine or bump, got {drift_shape!r}")
        sim = DiveSimulation(
            profile,
            LEMTimetable(dwell_s=lem_dwell_s),
            water_column=column,
            seed=seed,
            frame_scale=frame_scale,
            start=start,
            tilt_scale={camera: tilt_scale} if tilt_scale != 1.0 else None,
            leak_at_s={camera: leak_at_s} if leak_at_s is not None else None,
        )
        if camera not in sim.module_ids:
            raise ValueError(f"--camera must be one of {', '.join(sim.module_ids)}, got {camera!r}")
        clock = SimClock.synced(start, speed, epoch_s - begin_s / speed)
    except ValueError as exc:
        raise fail(str(exc)) from None
    if not (sensor_rate_hz > 0 and math.isfinite(sensor_rate_hz)):
        raise fail(f"--sensor-rate-hz must be > 0, got {sensor_rate_hz}")
    cfg = AgentConfig(
        module=camera,
        connect=connect,
        outbox=outbox or Path(f"lrm-{camera}-outbox"),
        sensor_rate_hz=sensor_rate_hz,
        fsync=fsync,
        dive=dive,
        keys=module_keys,
        plaintext=plaintext,
    )
    agent = with_outbox(
        lambda: simulated_module(
            sim,
            cfg,
            clock,
            sched,
            readout_s=readout_s,
            lem_settle_s=lem_settle_s,
            clock_error_s=clock_error_s,
        )
    )
    agent.start()
    console.print(
        f"module {camera}: dive of {profile.duration_s / 60:.0f} min at {speed:g}x "
        f"({(profile.duration_s - begin_s) / speed / 60:.1f} min real"
        + (f", begins {begin_s / 60:.1f} min in, {profile.phase_at(begin_s)}" if begin_s else "")
        + f"), schedule {sched.name} v{sched.version}, "
        f"sending to {connect}, outbox {cfg.outbox}"
    )

    def finished() -> bool:
        if not exit_when_recovered or sim.dive_time_s(clock.now()) < profile.duration_s:
            return False
        agent.stop_producing()  # the dive is over: send what is left, then exit
        return agent.outbox.pending_count() == 0

    _run_module(agent, finished)


@app.command("replay")
def replay(
    folder: Annotated[Path, typer.Argument(help="A recorded frame set.")],
    camera: Annotated[str, typer.Option(help="Which camera's frames to replay.")] = "A",
    connect: ConnectOption = "tcp://127.0.0.1:5555",
    outbox: Annotated[Path | None, typer.Option(help="Outbox folder (default lrm-<camera>-replay).")] = None,
    speed: Annotated[
        float, typer.Option(help="1 = recorded pace, 10 = ten times faster, 0 = as fast as possible.")
    ] = 1.0,
    dive: DiveOption = None,
    keys: KeysOption = Path(DATA_DIR) / "keys",
    plaintext: PlaintextOption = False,
    log_level: Annotated[str, typer.Option(help="debug, info, warning.")] = "info",
) -> None:
    """Stream a recorded frame set over the module protocol, then exit when the ship has it all.

    Exits with status 3 if the ship at --connect is not the right one."""
    from camcal.core.frameset import FrameSetError
    from lrm.agent import Agent, AgentConfig
    from lrm.clock import SystemClock
    from lrm.replay import ReplaySource

    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if speed < 0:
        raise fail("--speed must be >= 0")
    module_keys = link_keys(keys, camera, plaintext)
    clock = SystemClock()
    try:
        source = ReplaySource(folder, camera, clock, speed)
    except FrameSetError as exc:
        raise fail(str(exc)) from None
    if not len(source):
        raise fail(f"{folder}: no usable frame of camera {camera!r} in the manifest")
    cfg = AgentConfig(
        module=camera,
        connect=connect,
        outbox=outbox or Path(f"lrm-{camera}-replay"),
        dive=dive,
        keys=module_keys,
        plaintext=plaintext,
    )
    agent = with_outbox(lambda: Agent(cfg, clock=clock, source=source))
    agent.start()
    console.print(f"replaying {len(source)} frames of camera {camera} from {folder} to {connect}")
    failed = _run_until_signal(
        agent,
        lambda: (agent.capture_done() and agent.outbox.pending_count() == 0) or refused(agent),
    )
    agent.stop()
    if refused(agent):
        raise fail(f"module {camera}: {agent.refusal.message}", code=REFUSED_EXIT)
    for name, why in source.skipped:
        console.print(labelled("skipped", "yellow", f"{name}: {why}"))
    console.print(
        f"sent {agent.counters['frames_captured']} frames; {agent.outbox.pending_count()} not acknowledged"
    )
    if failed:
        raise fail(f"replay of camera {camera} stopped after a failure (see the log above)", code=1)


# The real camera's commands (run, cameras, snap) and the module's doctor live beside this file; importing
# them registers them on `app`.
from camcal.cli import lrm_camera, lrm_doctor  # noqa: E402, F401
