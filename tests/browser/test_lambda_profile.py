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


@pytest.mark.parametrize("width", [1400, 768])
def test_the_live_profile_shows_every_visit_with_its_error_bars(
    page: Any, system: System, artifacts: Path, width: int
) -> None:
    wait_until(lambda: sum(len(v) for v in _visits(system).values()) >= 3, 120, "three λ_att visits")
    page.set_viewport_size({"width": width, "height": 1000})
    page.goto(system.url("/"))
    page.wait_for_function(f"() => ({PROFILE_POINTS})('#att-depth') >= 3", timeout=60_000)
    series = _visits(system)
    shown = page.evaluate(PROFILE_POINTS, "#att-depth")
    stored = sum(1 for pts in series.values() for p in pts if p["lambda_att_m"] is not None)
    assert shown >= min(stored, 3)
    # Each point carries its statistical error bar, and its hover says what the point is.
    trace = page.evaluate(
        "() => document.querySelector('#att-depth').data.find(t => t.showlegend !== false && t.error_x)"
    )
    assert all(e > 0 for e in trace["error_x"]["array"])
    assert "frames" in trace["text"][0] and "LEM depth" in trace["text"][0]
    # Depth points down; the profile sits beside the time series on a desk, below it on a tablet.
    assert page.evaluate(
        "() => document.querySelector('#att-depth')._fullLayout.yaxis.range[0]"
    ) > page.evaluate("() => document.querySelector('#att-depth')._fullLayout.yaxis.range[1]")
    time_box = page.locator("#att-time").bounding_box()
    depth_box = page.locator("#att-depth").bounding_box()
    if width >= 1200:
        assert abs(time_box["y"] - depth_box["y"]) < 5 and depth_box["x"] > time_box["x"]
    page.locator("#attenuation-panel").scroll_into_view_if_needed()
    page.locator("#attenuation-panel").screenshot(path=artifacts / f"live-lambda-profile-{width}.png")
    # Smoothing is a display option: a line appears, labelled with its span; the points stay.
    if sum(len(v) for v in series.values()) >= 9:
        page.select_option("#att-smooth", "3")
        page.wait_for_function(
            "() => document.querySelector('#att-time').data.some(t => /mean of 3 visits/.test(t.name || ''))"
        )


@pytest.mark.parametrize("width", [1400, 768])
def test_the_review_profile_renders_the_run_with_data(
    page: Any, system: System, artifacts: Path, width: int
) -> None:
    wait_until(lambda: sum(len(v) for v in _visits(system).values()) >= 3, 120, "three λ_att visits")
    page.set_viewport_size({"width": width, "height": 1100})
    page.goto(system.url("/review#tab=attenuation"))
    page.wait_for_function(f"() => ({PROFILE_POINTS})('#att-series-depth') >= 3", timeout=60_000)
    page.wait_for_function("() => document.querySelector('#att-series-time').dataset.drawn === '1'")
    labels = page.evaluate("() => document.querySelector('#att-series-depth')._fullLayout.yaxis.title.text")
    assert "depth" in labels
    page.locator("#tab-attenuation .panel").nth(1).screenshot(
        path=artifacts / f"review-lambda-profile-{width}.png"
    )
