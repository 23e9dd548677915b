"""``camcal lrm run|cameras|snap``: a module on its real camera, and the technician's bench commands.

``run --camera aravis:ID`` drives a GenICam camera (USB3 Vision, GigE Vision)
through Aravis, ``run --camera v4l2:/dev/video0`` a UVC camera through OpenCV.
``cameras`` lists the GenICam cameras this computer sees, ``snap`` takes one
frame and says what the camera applied. The commands register on
`camcal.cli.lrm.app`; what they need is imported when they run.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Annotated, Any

import typer

from camcal.cli.common import console, fail, labelled
from camcal.cli.lrm import (
    DiveOption,
    KeysOption,
    PlaintextOption,
    _run_module,
    app,
    link_keys,
    load_schedule,
    with_outbox,
)

CameraSpec = Annotated[
    str,
    typer.Option(
        "--camera",
        envvar="CAMCAL_LRM_CAMERA",
        help="The camera: aravis:ID (a GenICam camera by its id, serial or address: `camcal lrm "
        "cameras`) or v4l2:DEVICE (a UVC camera, /dev/video0).",
    ),
]
PixelFormatOption = Annotated[
    str,
    typer.Option(
        envvar="CAMCAL_LRM_PIXEL_FORMAT",
        help="GenICam pixel format: Mono8, Mono10, Mono12, Mono14 or Mono16 (unpacked).",
    ),
]
WidthOption = Annotated[int | None, typer.Option(help="Region width [px], centred (default: the sensor's).")]
HeightOption = Annotated[
    int | None, typer.Option(help="Region height [px], centred (default: the sensor's).")
]
PacketSizeOption = Annotated[
    int | None,
    typer.Option(
        envvar="CAMCAL_LRM_PACKET_SIZE_B",
        help="GigE Vision only: GVSP packet size [bytes], e.g. 8000 with jumbo frames on the link "
        "(default: the camera's).",
    ),
]


def _aravis_missing(exc: Exception) -> typer.Exit:
    return fail(f"{exc}", code=2)


def open_camera(
    spec: str,
    module: str,
    *,
    pixel_format: str = "Mono8",
    width_px: int | None = None,
    height_px: int | None = None,
    wait: bool = False,
    frame_timeout_s: float = 3.0,
    packet_size_b: int | None = None,
    v4l2: dict[str, Any] | None = None,
) -> Any:
    """The camera ``spec`` names (``aravis:ID`` or ``v4l2:DEVICE``), opened; a one-line error else."""
    from lrm.camera import CameraError

    kind, _, device = spec.partition(":")
    if kind not in ("aravis", "v4l2") or not device:
        raise fail(f"--camera must be aravis:ID or v4l2:DEVICE, got {spec!r}")
    try:
        if kind == "aravis":
            from lrm.cameras.aravis import AravisCamera

            return AravisCamera(
                device,
                module,
                pixel_format=pixel_format,
                width_px=width_px,
                height_px=height_px,
                wait=wait,
                frame_timeout_s=frame_timeout_s,
                packet_size_b=packet_size_b,
            )
        from lrm.cameras.v4l2 import V4L2Camera

        return V4L2Camera(int(device) if device.isdigit() else device, module, **(v4l2 or {}))
    except (CameraError, ValueError) as exc:
        raise fail(str(exc)) from None


@app.command("cameras")
def cameras(
    as_json: Annotated[bool, typer.Option("--json", help="One JSON object per camera, a line each.")] = False,
) -> None:
    """List the GenICam cameras this computer sees: id, model, serial, pixel formats, ranges.

    Exits with status 1 when it sees none. A camera another program holds (a running module) is
    listed without its details."""
    import dataclasses
    import json

    from rich.table import Table

    from lrm.cameras.aravis import AravisMissing, list_cameras

    try:
        found = list_cameras()
    except AravisMissing as exc:
        raise _aravis_missing(exc) from None
    if as_json:
        for c in found:
            typer.echo(json.dumps(dataclasses.asdict(c)))
    else:
        table = Table("id", "model", "serial", "address", "mono formats", "exposure", "gain", "sensor")
        for c in found:
            mono = ", ".join(f for f in c.pixel_formats if f.startswith("Mono")) or "–"
            exp = f"{c.exposure_range_s[0]:g} – {c.exposure_range_s[1]:g} s" if c.exposure_range_s else "–"
            gain = f"{c.gain_range_db[0]:g} – {c.gain_range_db[1]:g} dB" if c.gain_range_db else "–"
            size = f"{c.sensor_px[0]} x {c.sensor_px[1]}" if c.sensor_px else "–"
            model = f"{c.vendor} {c.model}".strip()
            table.add_row(c.device_id, model, c.serial, f"{c.protocol} {c.address}", mono, exp, gain, size)
        console.print(table)
        for c in found:
            if c.error:
                console.print(labelled("warning:", "yellow", f"{c.device_id}: {c.error}"))
            elif c.temperature_c is not None:
                console.print(f"{c.device_id}: {c.temperature_c:.1f} °C")
    if not found:
        raise fail(
            "no GenICam camera seen: check its cable and power (USB3: `lsusb`; GigE: the camera on "
            "this computer's subnet, jumbo frames)",
            code=1,
        )


@app.command("snap")
def snap(
    device: Annotated[str, typer.Option(help="The camera's id, serial or address (`camcal lrm cameras`).")],
    exposure_s: Annotated[float, typer.Option(help="Exposure [s].")],
    gain_db: Annotated[float, typer.Option(help="Gain [dB].")],
    out: Annotated[Path, typer.Option(help="PNG file to write (16-bit for Mono10 to Mono16).")],
    pixel_format: PixelFormatOption = "Mono8",
    width_px: WidthOption = None,
    height_px: HeightOption = None,
    packet_size_b: PacketSizeOption = None,
) -> None:
    """Take one frame with a GenICam camera and say what the camera applied (read back)."""
    import numpy as np

    from camcal.core.files import write_atomic
    from camcal.core.images import encode_png, full_scale
    from lrm.camera import CameraError

    cam = open_camera(
        f"aravis:{device}",
        "snap",
        pixel_format=pixel_format,
        width_px=width_px,
        height_px=height_px,
        packet_size_b=packet_size_b,
    )
    try:
        frame = cam.capture(exposure_s, gain_db)
    except (CameraError, ValueError) as exc:
        raise fail(str(exc), code=1) from None
    finally:
        cam.close()
    try:
        write_atomic(out, encode_png(frame.pixels, frame.bit_depth), fsync=True)
    except OSError as exc:
        raise fail(f"{out}: {exc.strerror or exc}", code=1) from None
    px = frame.pixels
    top = full_scale(px.dtype, frame.bit_depth)
    gray = 255.0 / top
    e = frame.extra
    console.print(f"camera {cam.device_id} ({cam.model}, serial {cam.serial})")
    console.print(
        f"exposure {frame.exposure_s:g} s (asked {e['requested_exposure_s']:g}), gain {frame.gain_db:g} dB "
        f"(asked {e['requested_gain_db']:g}): as the camera's registers read back"
    )
    console.print(
        f"{px.shape[1]} x {px.shape[0]} px {cam.pixel_format} ({frame.bit_depth} bits, full scale {top}); "
        f"gray min {px.min() * gray:.1f}, median {float(np.median(px)) * gray:.1f}, "
        f"max {px.max() * gray:.1f}; {100 * np.count_nonzero(px >= top) / px.size:.2f} % saturated"
    )
    temp = (
        f", camera at {frame.extra['device_temperature_c']:.1f} °C" if cam.temperature_c is not None else ""
    )
    console.print(
        f"taken {frame.captured_at.isoformat().replace('+00:00', 'Z')} ({e['timestamp_source']} clock), "
        f"{1e3 * e['latency_s']:.0f} ms from trigger to frame{temp}; written to {out}"
    )


@app.command("run")
def run(
    camera: CameraSpec,
    module: Annotated[
        str, typer.Option(envvar="CAMCAL_LRM_MODULE", help="Module id written into every frame (A, B).")
    ] = "A",
    connect: Annotated[
        str, typer.Option(envvar="CAMCAL_LRM_CONNECT", help="The ship's ingest: tcp://HOST:PORT.")
    ] = "tcp://127.0.0.1:5555",
    outbox: Annotated[
        Path | None,
        typer.Option(envvar="CAMCAL_LRM_OUTBOX", help="SD-card outbox folder (default lrm-<module>-outbox)."),
    ] = None,
    schedule: Annotated[
        str, typer.Option(envvar="CAMCAL_LRM_SCHEDULE", help="Schedule preset or a schedule JSON file.")
    ] = "trex",
    lem_epoch: Annotated[
        str | None,
        typer.Option(
            envvar="CAMCAL_LRM_LEM_EPOCH",
            help="UTC time (ISO 8601) at which the LEM's colour cycle started with its first wavelength; "
            "without it frames carry the schedule's wavelength and every shot is taken at once.",
        ),
    ] = None,
    lem_dwell_s: Annotated[float, typer.Option(help="Seconds the LEM shows each wavelength.")] = 60.0,
    lem_wavelengths: Annotated[
        str, typer.Option(help="The LEM's colour cycle in order [nm].")
    ] = "405,460,525",
    pixel_format: PixelFormatOption = "Mono8",
    width_px: WidthOption = None,
    height_px: HeightOption = None,
    frame_timeout_s: Annotated[
        float, typer.Option(help="How long past the exposure a frame may take to arrive [s].")
    ] = 3.0,
    packet_size_b: PacketSizeOption = None,
    exposure_range_s: Annotated[
        str, typer.Option(help="v4l2 only: the camera's exposure range MIN,MAX [s].")
    ] = "0.0001,1.0",
    gain_range_db: Annotated[
        str, typer.Option(help="v4l2 only: the camera's gain range MIN,MAX [dB].")
    ] = "0,24",
    gain_units_per_db: Annotated[
        float, typer.Option(help="v4l2 only: driver gain units per dB (10 for a driver in 0.1 dB steps).")
    ] = 1.0,
    gain_offset: Annotated[float, typer.Option(help="v4l2 only: driver gain value at 0 dB.")] = 0.0,
    dive: DiveOption = None,
    keys: KeysOption = Path("keys"),
    plaintext: PlaintextOption = False,
    log_level: Annotated[str, typer.Option(help="debug, info, warning.")] = "info",
) -> None:
    """Run a real module: its camera under the schedule, streaming to the ship.

    A GenICam camera (``--camera aravis:ID``) that is not there yet, or goes
    away, is no reason to stop: the module runs, the ship raises its camera
    alarm with the reason, and the module opens the camera again when it
    comes back. Its own ranges check the schedule and go to the ship (the
    control page checks schedules against them); its DeviceTemperature,
    where it has one, is sent as the housing temperature. A real module
    never exits because the ship is the wrong one: it keeps capturing to the
    SD card and keeps looking. Under systemd (deploy/camcal-lrm.service) it
    says when it is ready and feeds the watchdog while it works.
    """
    from camcal.cli.common import parse_floats
    from camcal.core.schedule import CameraLimits
    from camcal.core.utctime import parse_utc
    from lrm.agent import Agent, AgentConfig
    from lrm.clock import SystemClock
    from lrm.dive import LEMTimetable
    from lrm.runner import LemTimetableClock, ScheduleRunner

    logging.basicConfig(level=log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    sched = load_schedule(schedule)
    lem = None
    if lem_epoch is not None:
        try:
            epoch = parse_utc(lem_epoch)
            timetable = LEMTimetable(
                tuple(int(w) for w in parse_floats(lem_wavelengths, "--lem-wavelengths")), lem_dwell_s
            )
        except ValueError as exc:
            raise fail(f"--lem-epoch/--lem-dwell-s/--lem-wavelengths: {exc}") from None
        lem = LemTimetableClock(timetable, epoch)
    clock = SystemClock()
    exp = parse_floats(exposure_range_s, "--exposure-range-s")
    gain = parse_floats(gain_range_db, "--gain-range-db")
    if len(exp) != 2 or len(gain) != 2:
        raise fail("--exposure-range-s and --gain-range-db take MIN,MAX")
    cam = open_camera(
        camera,
        module,
        pixel_format=pixel_format,
        width_px=width_px,
        height_px=height_px,
        wait=True,
        frame_timeout_s=frame_timeout_s,
        packet_size_b=packet_size_b,
        v4l2={
            "clock": clock,
            "exposure_range_s": (exp[0], exp[1]),
            "gain_range_db": (gain[0], gain[1]),
            "gain_units_per_db": gain_units_per_db,
            "gain_offset": gain_offset,
        },
    )
    limits_of = getattr(cam, "limits", None)
    limits = (
        limits_of() if limits_of else CameraLimits(cam.exposure_range_s, cam.gain_range_db, cam.gain_step_db)
    )
    problems = limits.problems(sched) if limits is not None else []
    if problems:
        cam.close()
        raise fail("; ".join(f"schedule {field}: {why}" for field, why in problems))
    try:  # after the camera: its problems are the ones to fix first
        module_keys = link_keys(keys, module, plaintext)
    except typer.Exit:
        cam.close()
        raise
    sensors = None
    if hasattr(cam, "temperature_c"):  # a GenICam camera's DeviceTemperature, from its first frame
        from lrm.cameras import CameraTemperature

        sensors = CameraTemperature(cam, module)
    runner = ScheduleRunner(cam, clock, sched, lem=lem)
    cfg = AgentConfig(
        module=module,
        connect=connect,
        outbox=outbox or Path(f"lrm-{module}-outbox"),
        dive=dive,
        keys=module_keys,
        plaintext=plaintext,
        sensor_rate_hz=1.0,
        sensor_batch_s=10.0,
    )
    agent = with_outbox(
        lambda: Agent(
            cfg,
            clock=clock,
            runner=runner,
            sensors=sensors,
            camera_limits=limits_of or limits,
            camera_info=getattr(cam, "info", None),
        )
    )
    agent.start()
    what = getattr(cam, "device_id", None) or getattr(cam, "device_path", camera)
    console.print(
        f"module {module}: camera {what}, schedule {sched.name} v{sched.version}, "
        f"sending to {connect}, outbox {cfg.outbox}"
    )
    try:
        _run_module(agent, lambda: False, stop_on_refusal=False)
    finally:
        cam.close()
