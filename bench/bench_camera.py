"""A module's real camera path through the GigE Vision emulator: frames/s and capture latency at the
full 2048 x 2048 sensor, with and without lost packets.

Each case starts ``arv-fake-gv-camera-0.8`` on 127.0.0.1 (``-r N`` drops N GVSP packets in a
thousand; the emulator cannot resend them), opens it as a module does (`lrm.cameras.aravis.
AravisCamera`, Width/Height set to the whole sensor) and takes shots at 1 ms:

* ``capture``: trigger to a numpy frame, as `AravisCamera.capture` returns it (settings read back,
  incomplete frames shot again up to 2 times, then refused);
* ``floor``: the same trigger and wait on the same stream, without reading the frame out (the
  emulator's own pace and the transfer): ``capture / floor`` is what camcal adds;
* ``stored``: capture, PNG encoding and the outbox's fsynced write (image, folder, row), as the
  module stores each frame before offering it to the ship.

Frames/s here are the emulator's and this machine's, on the loopback (no cable): a real camera's
link and exposure set its own. Run: ``.venv/bin/python bench/bench_camera.py [--shots N]``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camcal.core.images import encode_png
from lrm.camera import CaptureFailed
from lrm.cameras.aravis import AravisCamera
from lrm.outbox import Outbox
from tests.utils.aravis import FakeGigECamera

EXPOSURE_S = 0.001


def floor_ms(cam: AravisCamera, shots: int) -> float:
    """Median trigger-to-buffer time on the camera's own stream, the frame not read out."""
    times = []
    stream = cam._stream
    for _ in range(shots):
        t0 = time.perf_counter()
        cam._cam.software_trigger()
        buf = stream.timeout_pop_buffer(2_000_000)
        times.append(time.perf_counter() - t0)
        if buf is not None:
            stream.push_buffer(buf)
    return 1e3 * statistics.median(times)


def run_case(fmt: str, lost: int, shots: int, size: int, outbox: Path | None) -> dict[str, object]:
    with FakeGigECamera(lost_per_thousand=lost) as gige:
        cam = AravisCamera(
            gige.serial, "A", pixel_format=fmt, width_px=size, height_px=size, frame_timeout_s=0.5
        )
        cam.capture(EXPOSURE_S, 0.0)  # settings written, stream warm
        floor = floor_ms(cam, max(5, shots // 3)) if lost == 0 else float("nan")
        latencies, refused = [], 0
        box = Outbox(outbox, "A", fsync=True) if outbox is not None else None
        t0 = time.perf_counter()
        for seq in range(1, shots + 1):
            s = time.perf_counter()
            try:
                f = cam.capture(EXPOSURE_S, 0.0)
            except CaptureFailed:
                refused += 1
                continue
            latencies.append(time.perf_counter() - s)
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
        if box is not None:
            box.close()
        stats = cam.stream_statistics()
        cam.close()
    ok = len(latencies)
    return {
        "format": fmt,
        "size": size,
        "lost": lost,
        "stored" if outbox is not None else "frames": ok,
        "refused": refused,
        "incomplete": cam.counters["incomplete"],
        "fps": ok / took,
        "median_ms": 1e3 * statistics.median(latencies) if latencies else float("nan"),
        "p90_ms": 1e3 * statistics.quantiles(latencies, n=10)[-1] if len(latencies) >= 10 else float("nan"),
        "floor_ms": floor,
        "missing_packets": stats.get("n_missing_packets", 0),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--shots", type=int, default=30)
    args = ap.parse_args()
    cases = [
        ("Mono8", 0, 2048, False),
        ("Mono16", 0, 2048, False),
        ("Mono8", 0, 2048, True),
        ("Mono8", 5, 2048, False),
        ("Mono8", 5, 512, False),
    ]
    print(f"{args.shots} shots of {EXPOSURE_S * 1e3:g} ms each; frames/s over all shots, refused ones in")
    head = ("case", "ok", "refused", "incompl.", "frames/s", "median", "p90", "vs floor")
    print(f"{head[0]:<34} " + " ".join(f"{h:>8}" for h in head[1:]))
    with tempfile.TemporaryDirectory() as tmp:
        for fmt, lost, size, store in cases:
            r = run_case(fmt, lost, args.shots, size, Path(tmp) / f"{fmt}-{lost}-{size}" if store else None)
            name = (
                f"{fmt} {size}x{size}" + (f" -r {lost}" if lost else "") + (" +PNG+outbox" if store else "")
            )
            ok = r.get("stored", r.get("frames"))
            ratio = r["median_ms"] / r["floor_ms"] if r["floor_ms"] == r["floor_ms"] else float("nan")
            print(
                f"{name:<34} {ok:>8} {r['refused']:>8} {r['incomplete']:>8} {r['fps']:>8.1f} "
                f"{r['median_ms']:>6.0f}ms {r['p90_ms']:>6.0f}ms {ratio:>8.2f}"
            )


if __name__ == "__main__":
    main()
