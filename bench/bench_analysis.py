"""Benchmark of the I_center analysis, as ratios against floors measured in the same run.

1. analysis of one 5 MP frame already in memory (centroid search on the full
   frame, crop, profile, fit) against one read pass over it (``frame.max()``);
2. ``camcal analyze`` on a whole 5 MP frame set (all cores, decoding
   included) against decoding the same PNGs and nothing else on one core,
   with camcal's decoder (``camcal.core.images.read_frame``: libdeflate for
   the unfiltered PNGs modules write); OpenCV's decoder is timed beside it.
   The same on 24 of the frames separates what each frame costs from what
   does not depend on the set's size (starting Python, imports, stacking, output);
3. ``camcal analyze FILE`` on one frame of the set against decoding that frame
   (what is left is starting Python, the imports and the analysis).

Run: ``.venv/bin/python bench/bench_analysis.py [--frames N]``.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2

from analysis import analyze_frame
from camcal.core.frameset import read_manifest
from camcal.core.images import read_frame
from camcal.core.schedule import Schedule
from lrm.simset import SimulationSpec, simulate_frame_set


def median_time(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=4, help="frames per setting (x 2 cameras, 9 settings)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "set"
        sched = Schedule(
            name="bench", exposures_s=(0.05, 0.07, 0.11), gains_db=(2.0, 8.0, 14.0), repeats=args.repeats
        )
        print(f"building a 5 MP frame set of {sched.n_frames * 2} frames ...", flush=True)
        simulate_frame_set(folder, SimulationSpec(schedule=sched, seed=5))
        rows = read_manifest(folder)
        paths = [folder / r.file for r in rows]
        frames = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths[:24]]

        # 1. one frame in memory against one read pass
        per_frame, read_pass = [], []
        for f in frames:
            analyze_frame(f)  # warm
            per_frame.append(median_time(lambda f=f: analyze_frame(f), 7))
            read_pass.append(median_time(lambda f=f: f.max(), 21))
        t_an, t_max = statistics.median(per_frame), statistics.median(read_pass)

        # 2. the whole set through the CLI against decoding alone on one core
        t_decode = median_time(lambda: [read_frame(p) for p in paths], 2)
        t_decode_cv = median_time(lambda: [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in paths], 2)
        cmd = [
            sys.executable,
            "-c",
            "from camcal.cli import main; main()",
            "analyze",
            str(folder),
            "--quiet",
            "--json",
            str(Path(tmp) / "r.json"),
        ]
        t_cli = median_time(lambda: subprocess.run(cmd, check=True, capture_output=True), 2)

        # 3. what does not depend on the set's size: the same on a subset of 24 frames
        small = Path(tmp) / "small"
        small.mkdir()
        (small / "setup.json").write_bytes((folder / "setup.json").read_bytes())
        lines = (folder / "manifest.csv").read_text().splitlines(keepends=True)
        picked = lines[1 :: max(1, (len(lines) - 1) // 24)][:24]
        (small / "manifest.csv").write_text(lines[0] + "".join(picked))
        small_paths = [folder / r.file for r in read_manifest(small)]
        for r in read_manifest(small):
            (small / r.file).parent.mkdir(parents=True, exist_ok=True)
            (small / r.file).symlink_to(folder / r.file)
        t_decode_small = median_time(lambda: [read_frame(p) for p in small_paths], 2)
        cmd_small = [*cmd[:4], str(small), *cmd[5:]]
        t_cli_small = median_time(lambda: subprocess.run(cmd_small, check=True, capture_output=True), 2)

        # 4. one frame file
        one = paths[0]
        t_decode_one = median_time(lambda: read_frame(one), 7)
        cmd_one = [*cmd[:4], str(one), "--quiet"]
        t_cli_one = median_time(lambda: subprocess.run(cmd_one, check=True, capture_output=True), 5)

    print()
    print("| figure | time | floor | ratio | aim |")
    print("| --- | --- | --- | --- | --- |")
    print(
        f"| analysis of one 5 MP frame in memory vs `frame.max()` | {t_an * 1e3:.2f} ms | "
        f"{t_max * 1e3:.3f} ms | {t_an / t_max:.1f}x | <= 20x |"
    )
    print(
        f"| `camcal analyze` on {len(paths)} frames vs PNG decoding on one core | {t_cli:.2f} s | "
        f"{t_decode:.2f} s | {t_cli / t_decode:.2f}x | <= 0.8x |"
    )
    n_more = len(paths) - len(small_paths)
    per_frame, per_decode = (t_cli - t_cli_small) / n_more, (t_decode - t_decode_small) / n_more
    print(
        f"| `camcal analyze`, each frame beyond the first {len(small_paths)} vs decoding it | "
        f"{per_frame * 1e3:.1f} ms | {per_decode * 1e3:.1f} ms | {per_frame / per_decode:.2f}x |  |"
    )
    print(
        f"| `camcal analyze` on {len(small_paths)} frames (start, imports, threads, output) | "
        f"{t_cli_small:.2f} s | {t_decode_small:.2f} s |  |  |"
    )
    print(
        f"| `camcal analyze FILE` on one frame vs decoding it | {t_cli_one:.2f} s | "
        f"{t_decode_one * 1e3:.1f} ms | {t_cli_one - t_decode_one:.2f} s more | <= 0.5 s more |"
    )
    print(
        f"| camcal's PNG decoding vs OpenCV's (`cv2.imread`), {len(paths)} frames, one core | "
        f"{t_decode:.2f} s | {t_decode_cv:.2f} s | {t_decode / t_decode_cv:.2f}x |  |"
    )


if __name__ == "__main__":
    main()
