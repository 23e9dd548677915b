"""The λ_att series check itself: honest errors pass it nearly always, wrong ones never.

Synthetic series of the live station test's size (87 points over three
wavelengths) with Gaussian pulls: at a true pull RMS of 1 the check may fail
only as rarely as its 99 % bands allow; with errors halved or doubled it
fails every time.
"""

from __future__ import annotations

import numpy as np

from tests.utils.series_check import check_series, within_2sigma_band

TRUE_M = {405: 20.0, 460: 28.0, 525: 24.0}


def _series(rng: np.random.Generator, n_per_wl: int, err_scale: float) -> list[dict[str, float]]:
    points = []
    for wl, true in TRUE_M.items():
        for i in range(n_per_wl):
            err = 0.01 * true
            points.append(
                {
                    "wavelength_nm": wl,
                    "t_unix_s": float(i),
                    "lambda_att_m": true + err * rng.normal(),
                    "stat_err_m": err * err_scale,
                }
            )
    return points


def _failures(err_scale: float, seeds: int = 200) -> int:
    def truth(wl: int, t: float) -> float:
        return TRUE_M[wl]

    return sum(
        not check_series(_series(np.random.default_rng(seed), 29, err_scale), truth).passed
        for seed in range(seeds)
    )


def test_honest_errors_pass_nearly_always() -> None:
    # Four 99 % bands (three per-wavelength pull RMS, one share within 2 σ) and one overall
    # band: a few failures in 200 at most; measured: 6 in 1000 (the old fixed 80-98 % share: 94 in 1000).
    assert _failures(1.0) <= 6


def test_halved_or_doubled_errors_always_fail() -> None:
    assert _failures(0.5, 50) == 50
    assert _failures(2.0, 50) == 50


def test_the_share_within_2_sigma_band_widens_for_small_samples_only() -> None:
    assert within_2sigma_band(87)[1] == 1.0  # 87 of 87 within 2 σ: an honest sample's luck
    assert within_2sigma_band(25)[0] < 0.80
    lo, hi = within_2sigma_band(5000)
    assert lo == 0.80 and 0.98 < hi < 0.995
