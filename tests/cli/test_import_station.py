"""A station camcal's simulator never drew, imported and exported: the λ_att series against its truth.

`tests/utils/indepset.py` draws 27 min of a station with its own renderer,
LEM, sensor (black level 0: the dark noise clipped), schedule (each camera
cycling three exposures frame by frame, 90 s blocks of one wavelength) and
a water whose λ_att falls by 35 % in 8 min and rises again. The real
`camcal import` (two analysis processes, a real SQLite store) and `camcal
export` then give the series a scientist would read.

What failed here before: the import made no series at all; frames were
analysed without their camera's disk size; the far camera's faint frames
(8-25 gray over a zero black level) came out dark by the clipped noise; a
visit's frames spread along the changing water counted as noise.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from tests.utils.indepset import START, WAVELENGTHS, Station, visit_truth_m
from tests.utils.live import camcal_cli


@pytest.mark.slow
def test_an_imported_station_gives_a_series_whose_errors_cover_its_truth(tmp_path: Path) -> None:
    folder, data, out = tmp_path / "set", tmp_path / "data", tmp_path / "export"
    n = Station(seed=21).write(folder, START)
    res = camcal_cli("import", str(folder), "--data", str(data), "--workers", "2", timeout=300)
    said = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0, said
    assert f"{n} frames imported" in said and "17 λ_att visits" in said, said
    res = camcal_cli("export", "--data", str(data), "--out", str(out), "--format", "csv")
    assert res.returncode == 0, res.stderr

    with open(out / "frames.csv") as f:
        frames = list(csv.DictReader(f))
    lost = [r for r in frames if r["status"] != "ok" and r["reason"] != "no_source"]
    assert len(frames) == n and len(lost) <= 8, lost  # a LEM in the linear range is measured
    with open(out / "attenuation.csv") as f:
        points = list(csv.DictReader(f))
    assert {int(p["wavelength_nm"]) for p in points} == set(WAVELENGTHS)
    pulls, devs = [], []
    for p in points:
        truth = visit_truth_m(
            int(p["wavelength_nm"]),
            float(p["t_first_unix_s"]) - START.timestamp(),
            float(p["t_last_unix_s"]) - START.timestamp(),
        )
        lam, err = float(p["lambda_att_m"]), float(p["stat_err_m"])
        assert p["final"] in ("1", "True", "true") and int(p["n_pairs"]) == 3, p
        devs.append((lam - truth) / truth)
        pulls.append((lam - truth) / err)
    rms_dev = math.sqrt(np.mean(np.square(devs)))
    rms_pull = math.sqrt(np.mean(np.square(pulls)))
    mean_pull = float(np.mean(pulls))
    print(f"\n{len(points)} visits: RMS dev {100 * rms_dev:.2f} %, pulls {mean_pull:+.2f} RMS {rms_pull:.2f}")
    assert rms_dev < 0.006, devs
    assert abs(mean_pull) < 0.5 and 0.45 < rms_pull < 1.4, pulls
    assert max(abs(x) for x in pulls) < 3.5, pulls
