"""Are the calibrations' errors honest? Pulls against the simulator's truth over many seeds.

For each lab experiment, simulate ``--seeds`` frame sets (small sensor),
run the calibration, and compare every value with its true counterpart:
pull = (measured - true) / error. Honest one-sigma errors give pulls with
mean ~0 and spread ~1; about 68 % within 1, 95 % within 2.

    python bench/calibration_pulls.py --seeds 20 [--kinds air-scan,psf]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from camcal.calibrate import EXPERIMENTS
from lrm.labset import lab_spec, match_truth, truth_values, write_lab_set
from lrm.sim.camera import CameraModel


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--kinds", default=",".join(EXPERIMENTS))
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    camera = CameraModel(width_px=640, height_px=512, fov_deg=16.0)
    for kind in args.kinds.split(","):
        run, document = EXPERIMENTS[kind].run, EXPERIMENTS[kind].document
        pulls: dict[str, list[float]] = defaultdict(list)
        start = time.perf_counter()
        for seed in range(args.seeds):
            with tempfile.TemporaryDirectory() as tmp:
                out = Path(tmp) / "set"
                truth = write_lab_set(out, lab_spec(kind, camera=camera, seed=seed, repeats=args.repeats))
                doc = document(run(out, workers=1), "bench")
            for measured, true in match_truth(doc["values"], truth_values(truth)):
                where = true.get("sweep") or true.get("medium") or ""
                label = f"{true['quantity']} {true.get('wavelength_nm', '')} {where}"
                pulls[label.strip()].append((measured["value"] - true["value"]) / measured["err"])
        took = time.perf_counter() - start
        print(f"\n{kind}: {args.seeds} seeds, {took:.1f} s")
        print(f"  {'value':42s} {'mean':>6s} {'std':>6s} {'max|p|':>7s} {'<1σ':>5s} {'<2σ':>5s} {'<3σ':>5s}")
        for label, p in sorted(pulls.items()):
            a = np.abs(np.array(p))
            print(
                f"  {label:42s} {np.mean(p):+6.2f} {np.std(p):6.2f} {a.max():7.2f} "
                f"{np.mean(a < 1):5.0%} {np.mean(a < 2):5.0%} {np.mean(a < 3):5.0%}"
            )


if __name__ == "__main__":
    main()
