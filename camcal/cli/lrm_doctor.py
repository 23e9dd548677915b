"""``camcal lrm doctor``: is this module ready to dive? Its camera, keys, clock, SD card and ship link.

Each check prints one line, ``ok``, ``warning`` or ``FAIL``, with what to do;
the exit status is 1 when one fails. Nothing is sent to the ship: the link
check stops after the handshake (ZeroMQ, then CURVE with the module's key), so
a doctor run beside a running module leaves the ship's records alone.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import shutil
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any

import typer

from camcal.cli.common import console, fail, labelled
from camcal.cli.lrm import ConnectOption, KeysOption, PlaintextOption, app

#: A 5 MP Mono8 PNG of a camera frame (dark, noisy), when the card holds none to measure.
FRAME_BYTES_GUESS = 1.8e6
#: Frames an hour of a module at the T-REX pace (~1.2 s a frame).
FRAMES_PER_HOUR = 3000
#: ``adjtimex``'s status bit: the kernel's clock is not synchronised (no NTP/chrony discipline).
STA_UNSYNC = 0x0040
#: The kernel's answer when the clock is not synchronised.
TIME_ERROR = 5


@dataclass(frozen=True)
class Check:
    what: str
    level: str  # ok, warning, fail
    detail: str


class _Timex(ctypes.Structure):
    # struct timex (Linux): modes, then the fields adjtimex fills; padding for the reserved tail
    _fields_ = [
        ("modes", ctypes.c_uint),
        ("offset", ctypes.c_long),
        ("freq", ctypes.c_long),
        ("maxerror", ctypes.c_long),
        ("esterror", ctypes.c_long),
        ("status", ctypes.c_int),
        ("constant", ctypes.c_long),
        ("precision", ctypes.c_long),
        ("tolerance", ctypes.c_long),
        ("time_sec", ctypes.c_long),
        ("time_usec", ctypes.c_long),
        ("tick", ctypes.c_long),
        ("rest", ctypes.c_long * 32),
    ]


def clock_sync() -> tuple[bool, float] | None:
    """(synchronised, estimated error [s]) as the kernel says (``adjtimex``, read only), or None."""
    name = ctypes.util.find_library("c")
    if name is None:
        return None
    try:
        libc = ctypes.CDLL(name, use_errno=True)
        tx = _Timex()
        state = libc.adjtimex(ctypes.byref(tx))
    except (OSError, AttributeError):
        return None
    if state < 0:
        return None
    return state != TIME_ERROR and not tx.status & STA_UNSYNC, tx.esterror / 1e6


def check_clock() -> Check:
    from camcal.core.wire.limits import TIME_MIN

    now = datetime.now(UTC)
    if now < TIME_MIN:
        return Check(
            "clock",
            "fail",
            f"reads {now:%Y-%m-%d}: never set (a Raspberry Pi has no battery clock); point chrony at the "
            "ship's NTP server, or `sudo date -s` from the ship's time",
        )
    sync = clock_sync()
    if sync is None:
        return Check("clock", "warning", f"reads {now:%Y-%m-%d %H:%M:%S} UTC; its synchronisation is unknown")
    if not sync[0]:
        return Check(
            "clock",
            "warning",
            f"reads {now:%Y-%m-%d %H:%M:%S} UTC but is not synchronised: frames are stamped by it; "
            "start chrony (or systemd-timesyncd) with the ship's NTP server (docs/module.md)",
        )
    return Check("clock", "ok", f"synchronised, estimated error {sync[1] * 1e3:.0f} ms")


def check_keys(keys: Path, module: str, plaintext: bool) -> Check:
    from camcal.core import wire

    if plaintext:
        return Check("keys", "warning", "plaintext link: no encryption, no authentication (lab bench only)")
    try:
        wire.module_keys(keys, module)
    except wire.KeyFileError as exc:
        return Check("keys", "fail", str(exc))
    return Check("keys", "ok", f"module {module}'s key and the ship's key in {keys}")


def check_outbox(outbox: Path, min_free_gb: float) -> Check:
    where = outbox
    while not where.exists() and where != where.parent:
        where = where.parent
    free = shutil.disk_usage(where).free
    frames = sorted((outbox / "frames").glob("*/*.png")) if outbox.exists() else []
    sample = frames[-50:]
    size = sum(f.stat().st_size for f in sample) / len(sample) if sample else FRAME_BYTES_GUESS
    hours = free / (size * FRAMES_PER_HOUR)
    if outbox.exists():
        probe = outbox / f".doctor-{os.getpid()}"
        try:
            with probe.open("wb") as fh:
                fh.write(b"x")
                fh.flush()
                os.fsync(fh.fileno())
            probe.unlink()
        except OSError as exc:
            return Check(
                "outbox", "fail", f"{outbox} cannot be written ({exc.strerror or exc}): remount or swap"
            )
    said = (
        f"{free / 1e9:.1f} GB free at {where}: ~{hours:.0f} h of frames at {size / 1e6:.1f} MB each "
        f"({len(frames)} on the card)"
    )
    if free < min_free_gb * 1e9:
        return Check("outbox", "fail", f"{said}; below {min_free_gb:g} GB: copy the card off and free it")
    return Check(
        "outbox", "warning" if hours < 12 else "ok", said + ("; less than a dive's worth" * (hours < 12))
    )


def check_camera(spec: str, module: str) -> Check:
    from camcal.cli.lrm_camera import open_camera
    from lrm.camera import CameraError

    try:
        cam = open_camera(spec, module)
    except typer.Exit:
        return Check(
            "camera",
            "fail",
            f"{spec} cannot be opened (the line above says why); a running module holds its camera: "
            "`systemctl status camcal-lrm`",
        )
    try:
        lo = max(cam.exposure_range_s[0], min(1e-3, cam.exposure_range_s[1]))
        frame = cam.capture(lo, cam.gain_range_db[0])
    except (CameraError, ValueError) as exc:
        return Check("camera", "fail", f"opened but took no frame: {exc}")
    finally:
        cam.close()
    e, g = cam.exposure_range_s, cam.gain_range_db
    info: dict[str, Any] = frame.extra
    temp = f", {cam.temperature_c:.1f} °C" if getattr(cam, "temperature_c", None) is not None else ""
    return Check(
        "camera",
        "ok",
        f"{getattr(cam, 'model', spec)} ({getattr(cam, 'device_id', spec)}): "
        f"{frame.pixels.shape[1]} x {frame.pixels.shape[0]} px, {frame.bit_depth} bits, exposure "
        f"{e[0]:g} – {e[1]:g} s, gain {g[0]:g} – {g[1]:g} dB; a frame in "
        f"{1e3 * info.get('latency_s', 0.0):.0f} ms{temp}",
    )


def check_ship(connect: str, module: str, keys: Path, plaintext: bool, timeout_s: float) -> Check:
    import zmq

    from camcal.core import wire
    from lrm.shipcheck import ShipCheck

    try:
        module_keys = None if plaintext else wire.module_keys(keys, module)
    except wire.KeyFileError as exc:
        return Check("ship", "fail", f"no keys to try the link with: {exc}")
    check = ShipCheck(module, connect, None, module_keys)
    ctx = zmq.Context()
    sock = check.open(ctx)
    try:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not check.handshakes and check.refusal is None:
            check.watch()
            time.sleep(0.02)
    finally:
        check.close(sock)
        ctx.term()
    if check.handshakes:
        secure = "CURVE with the ship's key" if module_keys else "plaintext"
        return Check("ship", "ok", f"{connect} completes the link's handshake ({secure})")
    if check.refusal is not None:
        return Check("ship", "fail", check.refusal.message)
    return Check(
        "ship",
        "fail",
        f"nothing answers at {connect} within {timeout_s:g} s: is the ship's ingest running, TCP "
        "5555 open, the tether's network up (`ping` the ship)?",
    )


@app.command("doctor")
def doctor(
    camera: Annotated[
        str | None, typer.Option("--camera", help="The camera to check: aravis:ID or v4l2:DEVICE.")
    ] = None,
    module: Annotated[str, typer.Option(help="This module's id (A, B).")] = "A",
    connect: ConnectOption = "tcp://127.0.0.1:5555",
    keys: KeysOption = Path("keys"),
    plaintext: PlaintextOption = False,
    outbox: Annotated[Path | None, typer.Option(help="The outbox (default lrm-<module>-outbox).")] = None,
    min_free_gb: Annotated[float, typer.Option(help="Free space the SD card must keep [GB].")] = 2.0,
    timeout_s: Annotated[float, typer.Option(help="How long the ship may take to answer [s].")] = 5.0,
) -> None:
    """Check a module before a dive: camera, keys, clock, SD card (outbox) and the link to the ship.

    Stop the module first to check its camera (a camera serves one program). Exits with status 1
    when a check fails."""
    checks = []
    if camera is not None:
        checks.append(check_camera(camera, module))
    checks += [
        check_keys(keys, module, plaintext),
        check_clock(),
        check_outbox(outbox or Path(f"lrm-{module}-outbox"), min_free_gb),
        check_ship(connect, module, keys, plaintext, timeout_s),
    ]
    style = {"ok": "green", "warning": "yellow", "fail": "bold red"}
    for c in checks:
        console.print(
            labelled(
                f"{c.what:<7} {c.level.upper() if c.level == 'fail' else c.level}", style[c.level], c.detail
            )
        )
    failed = [c.what for c in checks if c.level == "fail"]
    if failed:
        raise fail(f"not ready: {', '.join(failed)}", code=1)
