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

``vs raw`` is camcal's median latency over the floor's. Every frame camcal returned (and, for the
``+outbox`` cases, every frame read back from the card) is checked whole: at 10 ms and 0 dB the
emulator draws a diagonal ramp whose offset is the frame's id, so a frame with any packet missing
(the buffer's old bytes left in its place) fails the check. ``broken`` counts those: it must be 0.

Frames/s are the emulator's and this machine's, over the loopback (no cable; the emulator computes
each frame on the same cores): a real camera's link and exposure set its own. Run:
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


@dataclass
class Tally:
    latencies_s: list[float] = field(default_factory=list)
    busy_s: float = 0.0
    statuses: dict[str, int] = field(default_factory=dict)

    def median_ms(self) -> float:
        return 1e3 * statistics.median(self.latencies_s) if self.latencies_s else float("nan")

    def fps(self) -> float:
        return len(self.latencies_s) / self.busy_s if self.busy_s else float("nan")


def raw_shot(cam: AravisCamera, tally: Tally) -> None:
    """One shot of Aravis alone on the camera's stream: trigger, wait, give the buffer back."""
    ar, stream, device = cam._ar, cam._stream, cam._cam
    while (late := stream.try_pop_buffer()) is not None:  # (a late frame of an earlier shot)
        stream.push_buffer(late)
    t0 = time.perf_counter()
    device.software_trigger()
    buf = stream.timeout_pop_buffer(int((EXPOSURE_S + TIMEOUT_S) * 1e6))
    took = time.perf_counter() - t0
    tally.busy_s += took
    status = "timeout" if buf is None else buf.get_status()
    if buf is not None:
        stream.push_buffer(buf)
    name = "complete" if status == ar.BufferStatus.SUCCESS else getattr(status, "value_nick", status)
    tally.statuses[name] = tally.statuses.get(name, 0) + 1
    if name == "complete":
        tally.latencies_s.append(took)


def run_case(
    fmt: str, lost: int, size: int, packet_b: int | None, shots: int, card: Path | None
) -> dict[str, Any]:
    raw, ours = Tally(), Tally()
    refused, refusing_s, broken = 0, [], 0
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
                refused += 1
                continue
            if box is not None:
                box.add_frame(
                    "bench",
                    seq,
                    encode_png(f.pixels, f.bit_depth),
                    captured_at=datetime.now(UTC),
                    camera="A",
                    wavelength_nm=460,
                    exposure_s=f.exposure_s,
                    gain_db=f.gain_db,
                    depth_m=None,
                    schedule_version=1,
                )
            took = time.perf_counter() - t0
            ours.busy_s += took
            ours.latencies_s.append(took)
            broken += not whole_ramp(f.pixels, f.extra["frame_id"])
        stats = cam.stream_statistics()
        packet = int(cam._cam.get_integer("GevSCPSPacketSize"))
        cam.close()
    stored = None
    if box is not None:
        box.close()
        rows = read_manifest(card / "frames")
        stored = len(rows)
        broken += sum(not whole_ramp(decode_frame((card / "frames" / r.file).read_bytes())) for r in rows)
    return {
        "raw": raw,
        "ours": ours,
        "refused": refused,
        "refusing_ms": 1e3 * statistics.median(refusing_s) if refusing_s else None,
        "packet_b": packet,
        "incomplete": cam.counters["incomplete"],
        "timeouts": cam.counters["timeouts"],
        "stored": stored,
        "broken": broken,
        "missing_packets": int(stats.get("n_missing_packets", 0)),
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
        f"{args.shots} shots of each kind per case, {EXPOSURE_S * 1e3:g} ms at {GAIN_DB:g} dB; "
        f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the start"
    )
    head = ("raw ok/shots", "raw fps", "raw med", "ok", "refused", "incompl.", "broken")
    head += ("stored", "fps", "median", "vs raw")
    print(f"{'case':<30}" + "".join(f"{h:>13}" for h in head))
    notes = []
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, lost, size, packet_b, store in cases:
            card = Path(tmp) / f"{fmt}-{lost}-{size}-{packet_b}" if store else None
            r = run_case(fmt, lost, size, packet_b, args.shots, card)
            raw, ours = r["raw"], r["ours"]
            name = f"{fmt} {size}²" + (f" -r {lost}" if lost else "")
            name += (f" {packet_b // 1000} kB" if packet_b else "") + (" +outbox" if store else "")
            cells = (
                f"{len(raw.latencies_s)}/{args.shots}",
                f"{raw.fps():.1f}",
                f"{raw.median_ms():.0f} ms",
                len(ours.latencies_s),
                r["refused"],
                r["incomplete"],
                r["broken"],
                "-" if r["stored"] is None else r["stored"],
                f"{ours.fps():.1f}",
                f"{ours.median_ms():.0f} ms",
                f"{ours.median_ms() / raw.median_ms():.2f}",
            )
            print(f"{name:<30}" + "".join(f"{c!s:>13}" for c in cells), flush=True)
            if r["refusing_ms"] is not None:
                notes.append(
                    f"{name}: a refusal took a median {r['refusing_ms']:.0f} ms ({1 + 2} tries); "
                    f"{r['missing_packets']} packets missed ({r['packet_b']} B each)"
                )
    for n in notes:
        print(n)


if __name__ == "__main__":
    main()
