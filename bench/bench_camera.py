"""A module's real camera path through the GigE Vision emulator: frames/s and capture latency at the
full 2048 x 2048 sensor, Mono8 and Mono16, with and without lost packets.

Each case starts ``arv-fake-gv-camera-0.8`` on 127.0.0.1 (``-r N`` drops N GVSP packets in a
thousand; the emulator cannot resend them), opens it as a module does (`lrm.cameras.aravis.
AravisCamera`, Width/Height set to the whole sensor) and takes shots of 10 ms at 0 dB, two kinds
in turn on the one stream, so that a busy machine slows both alike:

* ``raw``, the floor: Aravis alone, as the shortest program would drive it (software trigger, wait
  for the buffer, give it back), the frame not read out;
* ``camcal``: `AravisCamera.capture`, trigger to a numpy frame (settings checked, frame copied out,
  device time mapped to UTC; an incomplete frame is shot again up to 2 times, then refused);
  ``+outbox`` adds the PNG and the outbox's fsynced write, as the module stores each frame.

The emulator looks for a software trigger 25 times a second (Aravis' fake camera: a fixed
40 ms clock), so trigger-to-frame times carry 0-40 ms of waiting for its clock, differently for
each kind (the shots alternate). The latency compared is therefore from the frame's arrival (its
first packet, as Aravis stamps it) to the frame in hand: ``arrive`` is the transfer and Aravis'
reassembly for ``raw``, the same plus camcal's own work for ``camcal``; ``lat. x`` is camcal's
median over the floor's. ``trig.`` is the trigger-to-frame time a module sees, clock included.
Frames/s count complete frames over the time spent in each kind's shots.

Every frame camcal returned (and, with ``+outbox``, every frame read back from the card) is
checked whole: at 10 ms and 0 dB the emulator draws a diagonal ramp from the frame's id
(`tests.utils.aravis.whole_ramp`), so a frame with any packet missing or misplaced fails.
``broken`` counts those: it must be 0.

Frames/s here are the emulator's and this machine's, over the loopback (no cable; the emulator
computes each frame on the same cores): a real camera's link and exposure set its own. Run:
``nice -n 10 .venv/bin/python bench/bench_camera.py [--shots N]``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camcal.core.frameset import read_manifest
from camcal.core.images import decode_frame, encode_png
from lrm.camera import CaptureFailed
from lrm.cameras.aravis import AravisCamera
from lrm.outbox import Outbox
from tests.utils.aravis import FakeGigECamera, whole_ramp

EXPOSURE_S, GAIN_DB = 0.01, 0.0  # the emulator's ramp at full contrast (1 ms draws a black frame)
TIMEOUT_S = 2.0


def _ms(values: list[float]) -> float:
    return 1e3 * statistics.median(values) if values else float("nan")


@dataclass
class Tally:
    """One kind of shot in one case: its complete frames' times, and the time all its shots took."""

    arrival_s: list[float] = field(default_factory=list)  # first packet -> frame in hand
    trigger_s: list[float] = field(default_factory=list)  # trigger -> frame in hand
    busy_s: float = 0.0

    def fps(self) -> float:
        return len(self.trigger_s) / self.busy_s if self.busy_s else float("nan")


def raw_shot(cam: AravisCamera, tally: Tally) -> None:
    """One shot of Aravis alone on the camera's stream: trigger, wait, give the buffer back."""
    stream, device = cam._stream, cam._cam
    while (late := stream.try_pop_buffer()) is not None:  # (a late frame of an earlier shot)
        stream.push_buffer(late)
    t0 = time.perf_counter()
    device.software_trigger()
    buf = stream.timeout_pop_buffer(int((EXPOSURE_S + TIMEOUT_S) * 1e6))
    done_ns, took = time.time_ns(), time.perf_counter() - t0
    tally.busy_s += took
    if buf is None:
        return
    if buf.get_status() == cam._ar.BufferStatus.SUCCESS:
        tally.trigger_s.append(took)
        tally.arrival_s.append((done_ns - buf.get_system_timestamp()) / 1e9)
    stream.push_buffer(buf)


def run_case(
    fmt: str, lost: int, size: int, packet_b: int | None, shots: int, card: Path | None
) -> dict[str, Any]:
    raw, ours = Tally(), Tally()
    refusing_s: list[float] = []
    broken = 0
    with FakeGigECamera(lost_per_thousand=lost) as gige:
        cam = AravisCamera(
            gige.serial,
            "A",
            pixel_format=fmt,
            width_px=size,
            height_px=size,
            frame_timeout_s=TIMEOUT_S,
            packet_size_b=packet_b,  # (None: the emulator's 1400 B; 8000: jumbo frames on a real link)
        )
        with contextlib.suppress(CaptureFailed):  # settings written, stream warm
            cam.capture(EXPOSURE_S, GAIN_DB)
        box = Outbox(card, "A", fsync=True) if card is not None else None
        for seq in range(1, shots + 1):
            raw_shot(cam, raw)
            t0 = time.perf_counter()
            try:
                f = cam.capture(EXPOSURE_S, GAIN_DB)
            except CaptureFailed:
                refusing_s.append(time.perf_counter() - t0)
                ours.busy_s += refusing_s[-1]
                continue
            if box is not None:
                box.add_frame(
                    "bench",
                    seq,
                    encode_png(f.pixels, f.bit_depth),
                    captured_at=f.captured_at,
                    camera="A",
                    wavelength_nm=460,
                    exposure_s=f.exposure_s,
                    gain_db=f.gain_db,
                    depth_m=None,
                    schedule_version=1,
                )
            done_ns, took = time.time_ns(), time.perf_counter() - t0
            ours.busy_s += took
            ours.trigger_s.append(took)
            ours.arrival_s.append((done_ns - f.extra["host_timestamp_ns"]) / 1e9)
            broken += not whole_ramp(f.pixels, f.extra["frame_id"])
        cam.close()
    stored = None
    if box is not None and card is not None:
        box.close()
        rows = read_manifest(card / "frames")
        stored = len(rows)
        broken += sum(not whole_ramp(decode_frame((card / "frames" / r.file).read_bytes())) for r in rows)
    return {
        "raw": raw,
        "ours": ours,
        "refused": len(refusing_s),
        "refusing_ms": _ms(refusing_s),
        "incomplete": cam.counters["incomplete"],
        "stored": stored,
        "broken": broken,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--shots", type=int, default=30, help="shots of each kind per case")
    args = ap.parse_args()
    cases = [  # pixel format, lost packets per thousand, region side [px], packet size [B], stored
        ("Mono8", 0, 2048, None, False),
        ("Mono16", 0, 2048, None, False),
        ("Mono8", 0, 2048, None, True),
        ("Mono16", 0, 2048, None, True),
        ("Mono8", 5, 2048, None, False),
        ("Mono16", 5, 2048, None, False),
        ("Mono8", 5, 2048, 8000, False),
        ("Mono8", 5, 512, None, True),
    ]
    print(
        f"{args.shots} shots of each kind per case, {EXPOSURE_S * 1e3:g} ms at {GAIN_DB:g} dB, "
        f"{datetime.now(UTC):%Y-%m-%d %H:%M} UTC; load average {os.getloadavg()[0]:.1f} on "
        f"{os.cpu_count()} cores at the start"
    )
    head = ("raw ok", "fps", "arrive", "ok", "refused", "incompl.", "broken", "stored", "fps")
    head += ("arrive", "trig.", "fps x", "lat. x")
    print(f"{'':<26}{'| raw (Aravis alone)':<27}{'| camcal':<81}| camcal / raw")
    print(f"{'case':<26}" + "".join(f"{h:>9}" for h in head))
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, lost, size, packet_b, store in cases:
            card = Path(tmp) / f"{fmt}-{lost}-{size}-{packet_b}" if store else None
            r = run_case(fmt, lost, size, packet_b, args.shots, card)
            raw, ours = r["raw"], r["ours"]
            name = f"{fmt} {size}²" + (f" -r {lost}" if lost else "")
            name += (f" {packet_b} B" if packet_b else "") + (" +outbox" if store else "")
            cells = (
                f"{len(raw.trigger_s)}/{args.shots}",
                f"{raw.fps():.1f}",
                f"{_ms(raw.arrival_s):.1f} ms",
                len(ours.trigger_s),
                r["refused"],
                r["incomplete"],
                r["broken"],
                "-" if r["stored"] is None else r["stored"],
                f"{ours.fps():.1f}",
                f"{_ms(ours.arrival_s):.1f} ms",
                f"{_ms(ours.trigger_s):.0f} ms",
                f"{ours.fps() / raw.fps():.2f}" if raw.fps() else "-",
                f"{_ms(ours.arrival_s) / _ms(raw.arrival_s):.2f}",
            )
            print(f"{name:<26}" + "".join(f"{c!s:>9}" for c in cells), flush=True)
            if r["refused"]:
                notes.append(f"{name}: a refusal (3 tries) took a median {r['refusing_ms']:.0f} ms")
    for n in notes:
        print(n)


if __name__ == "__main__":
    main()
