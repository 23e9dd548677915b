"""A schedule's preview judges each module's faint settings against its own dark level.

Two cameras see the LEM equally bright; one's dark level sits at 0 gray, the other's at
10. A setting that puts 4 gray of LEM light on the centre is too dark for the first
(4 < 5) and fine for the second (14). The preview used to assume 2.5 gray for both.
"""

from __future__ import annotations

import pytest

from ingest.derived import ResultRow, predict_settings


def row(module: str, dark_gray: float, exposure_s: float, lem_gray: float) -> ResultRow:
    return ResultRow(module, 460, exposure_s, 8.0, 0.0, 3420.0, "ok", dark_gray + lem_gray, lem_gray, 0.2)


def test_each_module_is_judged_against_its_own_dark_level() -> None:
    rows = [row("A", 0.0, 0.05, 40.0), row("A", 0.0, 0.1, 80.0), row("B", 10.0, 0.05, 40.0)]
    pred = predict_settings(rows, [(460, 0.005, 8.0), (460, 0.05, 8.0)], (5.0, 240.0))
    faint_a, bright_a = pred["A"]
    faint_b, _ = pred["B"]
    assert faint_a["center_gray"] == pytest.approx(4.0) and faint_a["verdict"] == "too_dark"
    assert faint_b["center_gray"] == pytest.approx(14.0) and faint_b["verdict"] == "ok"
    assert bright_a["center_gray"] == pytest.approx(40.0) and bright_a["verdict"] == "ok"


def test_a_module_without_a_measured_dark_level_takes_the_default() -> None:
    rows = [ResultRow("A", 460, 0.05, 8.0, 0.0, 3420.0, "rejected", 42.5, None, None)]
    pred = predict_settings(rows, [(460, 0.05, 8.0)], (5.0, 240.0))
    assert pred["A"][0]["center_gray"] == pytest.approx(42.5)
