"""Detection of the LEM: efficiency against the disk's summed signal-to-noise, and its cost.

Simulated 5 MP frames of both T-REX cameras (21.56 m and 41.62 m) at 460 nm
over a sweep of short exposures (from a LEM lost in the noise to a bright
one), with two sensors: camcal's default model and a noisier one (dark
offset 3 DN, ~1 DN read noise at 0 dB: the faint frames of issue 12), plus
frames with the LEM off. Per frame the truth knows the LEM centre's gray
above the dark level and the disk's summed signal-to-noise

    S/N = signal × sqrt(n_disk) / σ_pixel

(signal: the centre's mean gray above dark; n_disk: the disk's pixels;
σ_pixel: read, shot and quantisation noise of a dark pixel, in gray).

Prints, per S/N bin, how many frames were found (any status but
``no_source``) and how they were classified, the rates the issue asks for
(centre in the linear range -> ``ok``; visible but below it ->
``too_dark``; LEM off -> ``no_source``) and the analysis time per frame
(median, ms) of bright, faint and LEM-off frames.

Run: ``.venv/bin/python bench/bench_detect.py [--repeats N] [--scale S]``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections import Counter, defaultdict

import cv2
import numpy as np

from analysis import FrameConfig, analyze_frame
from camcal.core.frameset import TREX_FOCAL_PX
from lrm.sim import CameraModel, FrameRenderer, Placement
from lrm.sim.scene import water_preset

FOCAL_PX = TREX_FOCAL_PX
LINEAR = (5.0, 240.0)
VISIBLE_SNR = 30.0  # a disk this far above the noise is "visible" for the rates below


def cameras(scale: float) -> dict[str, CameraModel]:
    w, h = round(2448 * scale), round(2048 * scale)
    fov = 2 * math.degrees(math.atan((w / 2) / FOCAL_PX))
    return {
        "default": CameraModel(width_px=w, height_px=h, fov_deg=fov),
        "noisy": CameraModel(width_px=w, height_px=h, fov_deg=fov, black_level_gray=3.0, read_noise_e=25.0),
    }


def dark_noise_gray(cam: CameraModel, exposure_s: float, gain_db: float) -> float:
    g = cam.gray_per_electron * cam.gain_factor(gain_db)
    electrons = cam.dark_current_e_per_s * exposure_s
    return math.sqrt((electrons + cam.read_noise_e**2) * g * g + 1.0 / 12.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="frames per exposure, camera and sensor")
    parser.add_argument("--scale", type=float, default=1.0, help="sensor scale (1: 5 MP)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    water = water_preset("trex")
    rng = np.random.default_rng(12)
    rows = []  # (snr, expected_center_gray, dark_gray, status, reason, ms, lem_on, sensor)
    floors: list[float] = []  # ms of one read pass (frame.max()) over the same frames
    exposures = np.geomspace(1e-4, 0.03, 16)
    for model_name, cam in cameras(args.scale).items():
        for pl in (Placement("A", 21.56, 0.02, False), Placement("B", 41.62, 0.04, True)):
            r = FrameRenderer(cam, pl, water, seed=3)
            cfg = FrameConfig(linear_range_gray=LINEAR, expected_radius_px=r.disk_radius_px)
            n_disk = math.pi * r.disk_radius_px**2
            for gain_db in (0.0, 6.0):
                for exp in exposures:
                    expected = r.expected_center_gray(460, float(exp), gain_db)
                    g = cam.gray_per_electron * cam.gain_factor(gain_db)
                    dark = cam.black_level_gray + cam.dark_current_e_per_s * exp * g
                    signal = expected - dark
                    snr = signal * math.sqrt(n_disk) / dark_noise_gray(cam, float(exp), gain_db)
                    for _ in range(args.repeats):
                        off = tuple(rng.normal(0, 30.0 * args.scale, 2))
                        frame, _ = r.render(460, float(exp), gain_db, rng=rng, offset_px=off)
                        t0 = time.perf_counter()
                        res = analyze_frame(frame, cfg)
                        ms = 1e3 * (time.perf_counter() - t0)
                        t0 = time.perf_counter()
                        frame.max()
                        floors.append(1e3 * (time.perf_counter() - t0))
                        rows.append((snr, expected, dark, res.status, res.reason, ms, True, model_name))
            for _ in range(4 * args.repeats):
                exp = float(rng.choice(exposures))
                frame, _ = r.render(460, exp, 6.0, rng=rng, lem_on=False)
                t0 = time.perf_counter()
                res = analyze_frame(frame, cfg)
                ms = 1e3 * (time.perf_counter() - t0)
                rows.append((0.0, 0.0, 0.0, res.status, res.reason, ms, False, model_name))

    print(f"\n{len(rows)} frames of {round(2448 * args.scale)} x {round(2048 * args.scale)} px\n")
    print("| disk S/N | frames | found | ok | too_dark | saturated | no_source | other |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    bins = [0, 5, 10, 20, 30, 50, 100, 300, 1000, 1e9]
    by_bin: dict[int, Counter[str]] = defaultdict(Counter)
    for snr, _, _, status, reason, _, on, _ in rows:
        if on:
            k = int(np.searchsorted(bins, snr, side="right")) - 1
            by_bin[k][status if status == "ok" else str(reason)] += 1
    for k in sorted(by_bin):
        c = by_bin[k]
        n = sum(c.values())
        other = n - sum(c[x] for x in ("ok", "too_dark", "saturated", "no_source"))
        hi = "∞" if bins[k + 1] > 1e8 else f"{bins[k + 1]:g}"
        print(
            f"| {bins[k]:g}–{hi} | {n} | {100 * (n - c['no_source']) / n:.0f} % | {c['ok']} | "
            f"{c['too_dark']} | {c['saturated']} | {c['no_source']} | {other} |"
        )
    lo, hi = LINEAR
    in_range = [x for x in rows if x[6] and lo <= x[1] <= hi - 15]
    dark_vis = [x for x in rows if x[6] and x[1] < lo - 0.5 and x[0] >= VISIBLE_SNR]
    off = [x for x in rows if not x[6]]
    print()
    print(
        f"centre in the linear range (5-225 gray): {sum(x[3] == 'ok' for x in in_range)}/{len(in_range)} ok"
        f" ({100 * sum(x[3] == 'ok' for x in in_range) / max(len(in_range), 1):.1f} %)"
    )
    print(
        f"visible (S/N >= {VISIBLE_SNR:g}) but below 5 gray: "
        f"{sum(x[4] == 'too_dark' for x in dark_vis)}/{len(dark_vis)} too_dark"
    )
    print(f"LEM off: {sum(x[4] != 'no_source' for x in off)}/{len(off)} anything but no_source")
    for x in in_range:
        if x[3] != "ok":
            print(
                f"  in range but {x[4]}: centre {x[1]:.2f} gray (dark {x[2]:.2f}), "
                f"S/N {x[0]:.0f}, {x[7]} sensor"
            )
    bright = [x[5] for x in rows if x[6] and x[1] > 30]
    faint = [x[5] for x in rows if x[6] and 5 <= x[1] <= 30]
    offt = [x[5] for x in off]
    floor = statistics.median(floors)
    print(
        f"\nanalysis ms per frame, median: bright {statistics.median(bright):.2f}, "
        f"faint (5-30 gray) {statistics.median(faint):.2f}, LEM off {statistics.median(offt):.2f}; "
        f"one read pass (frame.max()) {floor:.3f} ms: "
        f"{statistics.median(bright) / floor:.0f}x / {statistics.median(faint) / floor:.0f}x / "
        f"{statistics.median(offt) / floor:.0f}x"
    )


if __name__ == "__main__":
    main()
