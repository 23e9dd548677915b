"""Measure the I_center repeatability floor of the per-visit λ_att series, and check its pulls.

The floor is what a visit's log ratio ``q = ln(I_near / I_far)`` misses the
truth by beyond its frames' own errors: over many visits on a station whose
water drifts (λ_att falls by 30 % and comes back), ``floor² = mean((q -
q_true)²) - mean(σ_frames²)``, per wavelength, with the floor set to 0. It holds what changes from visit
to visit and what the frames cannot see: the LEM's place in the frame, the
background fit's reach, the scattered light under the disk. Per camera
(the floor is applied to both) it is ``floor / sqrt(2)``; ``SHARE`` of it
(see there) is the ``series.repeatability`` of ``setup.json``.

Then, with the floors just measured, the same on stations of other seeds
(and, for the second, three frames per setting instead of five): the pulls
``(λ - truth) / stat_err`` should have an RMS near 1.

T-REX geometry and emission ratios, the small sensor (612 x 512 px, T-REX
plate scale), the quick-check schedule (0.05, 0.07, 0.11 s at 8 dB, 5
repeats), 75 s blocks, the far camera's frames 0.45 s after the near's.

Run: ``.venv/bin/python bench/repeatability.py [--visits N] [--trend-visits-max-s S]`` (~1 s
per visit; ``--trend-visits-max-s 0``: the trend priors of the fixed width only, as before the
series took them from the previous visits).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from camcal.core.frameset import SeriesSetup, Setup
from ingest.rolling import Sample, VisitSeries
from lrm.dive import DiveProfile, DiveSimulation, LEMTimetable, WaterColumn
from lrm.dive.station import station_results

SETTINGS = ((0.05, 8.0), (0.07, 8.0), (0.11, 8.0))
#: The share of the residual the floor takes. The residual is mostly a slowly varying bias, not
#: scatter: pulls built on all of it come out narrower than a Gaussian (~97 % within 2σ at an RMS
#: of 1), on three quarters of it they have an RMS of ~1.1 and ~94 % within 2σ.
SHARE = 0.75


def run(
    seed: int,
    n_visits: int,
    drop: float,
    floors: dict[int, float],
    repeats: int = 5,
    trend_visits_max_s: float = SeriesSetup().trend_visits_max_s,
) -> dict[int, list[tuple[float, ...]]]:
    """(λ, stat_err, truth, q, q_frames_err, q_true) per point, per wavelength."""
    profile = DiveProfile(
        deck_s=5.0, descent_m_per_s=100.0, test_stop_s=30.0, station_s=n_visits * 75.0, ascent_m_per_s=100.0
    )
    column = WaterColumn.with_station_bump(profile, drop)
    sim = DiveSimulation(profile, LEMTimetable(dwell_s=75.0), column, seed=seed, frame_scale=0.25)
    setup = Setup(
        series=SeriesSetup(
            repeatability=floors, repeatability_default=0.0, trend_visits_max_s=trend_visits_max_s
        )
    )
    series = VisitSeries(setup)
    t0, t1 = profile.window("station")
    for rows in station_results(sim, SETTINGS, repeats, t_from_s=t0, t_to_s=t1):
        series.add(Sample.from_result(r) for r in rows)
    series.close_all()
    epoch = sim.start.timestamp()
    out: dict[int, list[tuple[float, ...]]] = {}
    for p in series.points():
        wl = p["wavelength_nm"]
        truth = sim.lambda_att_pair_truth_m(wl, p["t_unix_s"] - epoch)
        q_true = setup.cameras["B"].distance_m - setup.cameras["A"].distance_m
        q_true = q_true / truth - math.log(setup.emission_ratio[wl].value)
        d = p["details"]
        out.setdefault(wl, []).append(
            (p["lambda_att_m"], p["stat_err_m"], truth, d["log_ratio"], d["terms"]["frames"], q_true)
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--visits", type=int, default=60, help="visits per station")
    parser.add_argument("--seeds", default="101,102", help="seeds of the stations the floor is measured on")
    parser.add_argument(
        "--trend-visits-max-s",
        type=float,
        default=SeriesSetup().trend_visits_max_s,
        help="series.trend_visits_max_s (0: every visit's trend prior the fixed one)",
    )
    args = parser.parse_args()
    t_start = time.time()
    pooled: dict[int, list[tuple[float, ...]]] = {}
    for seed in (int(s) for s in args.seeds.split(",")):
        for wl, rows in run(seed, args.visits, 0.3, {}, 5, args.trend_visits_max_s).items():
            pooled.setdefault(wl, []).extend(rows)
    print("\nfloor, drifting water (the floor set to 0):\n")
    print(
        f"| wavelength | visits | mean q - q_true | RMS q - q_true | σ_frames | floor on q | "
        f"{SHARE:g} of it per camera |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- |")
    floors = {}
    for wl, rows in sorted(pooled.items()):
        a = np.array(rows)
        dq = a[:, 3] - a[:, 5]
        floor = math.sqrt(max(float(np.mean(dq**2 - a[:, 4] ** 2)), 0.0))
        floors[wl] = round(SHARE * floor / math.sqrt(2.0), 4)
        print(
            f"| {wl} nm | {len(a)} | {dq.mean():+.4f} | {math.sqrt(np.mean(dq**2)):.4f} | "
            f"{np.mean(a[:, 4]):.4f} | {floor:.4f} | {floors[wl]:.4f} |"
        )
    print(f"\nrepeatability = {floors}\n")
    for seed, repeats in ((7, 5), (13, 3)):
        print(f"pulls with these floors, seed {seed}, {repeats} frames per setting:\n")
        print("| wavelength | visits | RMS rel. deviation | mean rel. error | pull RMS | within 2σ |")
        print("| --- | --- | --- | --- | --- | --- |")
        for wl, rows in sorted(run(seed, args.visits, 0.3, floors, repeats, args.trend_visits_max_s).items()):
            a = np.array(rows)
            dev = a[:, 0] / a[:, 2] - 1.0
            pull = (a[:, 0] - a[:, 2]) / a[:, 1]
            print(
                f"| {wl} nm | {len(a)} | {100 * math.sqrt(np.mean(dev**2)):.2f} % | "
                f"{100 * np.mean(a[:, 1] / a[:, 0]):.2f} % | {math.sqrt(np.mean(pull**2)):.2f} | "
                f"{100 * np.mean(np.abs(pull) < 2):.0f} % |"
            )
        print()
    print(f"\n({time.time() - t_start:.0f} s)")


if __name__ == "__main__":
    main()
