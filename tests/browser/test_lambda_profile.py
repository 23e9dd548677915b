"""λ_att per LEM visit in the browser: the depth profile beside the time series, live and in review."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import pytest

from tests.utils.system import System, wait_until

pytestmark = pytest.mark.browser

#: Points plotted in the profile (markers of the wavelength traces, error-bar helpers left out).
PROFILE_POINTS = """(sel) => {
  const div = document.querySelector(sel);
  if (!div || div.dataset.drawn !== '1' || !div.data) return 0;
  return div.data.filter(t => t.showlegend !== false && t.error_x).reduce((n, t) => n + t.x.length, 0);
}"""


def _visits(system: System) -> dict[str, list[dict[str, Any]]]:
    return httpx.get(system.url("/api/attenuation"), timeout=10).json()["series"]


def test_the_live_profile_shows_every_visit_with_its_error_bars(
    page: Any, system: System, artifacts: Path
) -> None:
    wait_until(lambda: sum(len(v) for v in _visits(system).values()) >= 3, 120, "three λ_att visits")
    page.set_viewport_size({"width": 1400, "height": 1000})
    page.goto(system.url("/"))
    page.wait_for_function(f"() => ({PROFILE_POINTS})('#att-depth') >= 3", timeout=60_000)
    series = _visits(system)
    stored = sum(1 for pts in series.values() for p in pts if p["lambda_att_m"] is not None)
    assert page.evaluate(PROFILE_POINTS, "#att-depth") >= min(stored, 3)
    # Each point carries its statistical error bar, and its hover says what the point is.
    trace = page.evaluate(
        "() => document.querySelector('#att-depth').data.find(t => t.showlegend !== false && t.error_x)"
    )
    assert all(e > 0 for e in trace["error_x"]["array"])
    assert "frames" in trace["text"][0] and "LEM depth" in trace["text"][0]
    # Depth points down; on a desk the profile sits beside the time series.
    lo, hi = page.evaluate("() => document.querySelector('#att-depth')._fullLayout.yaxis.range")
    assert lo > hi
    # Both boxes in one frame: the live page re-renders as events come (a banner, an alarm above),
    # and two separate reads could straddle a shift of everything below it.
    time_box, depth_box = page.evaluate(
        "() => ['#att-time', '#att-depth'].map(s => document.querySelector(s).getBoundingClientRect())"
        ".map(r => ({x: r.x, y: r.y}))"
    )
    assert abs(time_box["y"] - depth_box["y"]) < 5 and depth_box["x"] > time_box["x"]
    page.locator("#attenuation-panel").screenshot(path=artifacts / "live-lambda-profile-1400.png")
    # Smoothing is a display option: a line labelled with its span appears, the points stay.
    if sum(len(v) for v in series.values()) >= 9:
        page.select_option("#att-smooth", "3")
        page.wait_for_function(
            "() => document.querySelector('#att-time').data.some(t => /mean of 3 visits/.test(t.name || ''))"
        )
        assert page.evaluate(PROFILE_POINTS, "#att-depth") >= 3
    # A tablet: the profile below the time series, still drawn with its points.
    page.set_viewport_size({"width": 768, "height": 1000})
    page.wait_for_function(
        "() => document.querySelector('#att-depth').getBoundingClientRect().top > "
        "document.querySelector('#att-time').getBoundingClientRect().bottom - 5"
    )
    assert page.evaluate(PROFILE_POINTS, "#att-depth") >= 3
    page.locator("#attenuation-panel").screenshot(path=artifacts / "live-lambda-profile-768.png")


def test_the_review_profile_renders_the_run_with_data(page: Any, system: System, artifacts: Path) -> None:
    wait_until(lambda: sum(len(v) for v in _visits(system).values()) >= 3, 120, "three λ_att visits")
    for width in (1400, 768):
        page.set_viewport_size({"width": width, "height": 1100})
        page.goto(system.url("/review#tab=attenuation"))
        page.wait_for_function(f"() => ({PROFILE_POINTS})('#att-series-depth') >= 3", timeout=60_000)
        page.wait_for_function("() => document.querySelector('#att-series-time').dataset.drawn === '1'")
        title = page.evaluate(
            "() => document.querySelector('#att-series-depth')._fullLayout.yaxis.title.text"
        )
        assert "depth" in title
        panel = page.locator("#tab-attenuation .panel").nth(1)
        panel.screenshot(path=artifacts / f"review-lambda-profile-{width}.png")
