"""The pages at a phone's width (390 px), measured in the browser rather than judged by eye.

At 390 px the λ_att plots were ~100 px high with plotly's date line over their time ticks, the
review's span selector ran out of its card, the linearity figure's axis labels ran into each other,
the frame detail's legend covered its data, the depth profile labelled round depths between the
stops rather than the stops that hold its points, and LRM-B's markers hid LRM-A's on the timeline.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path
from typing import Any

import pytest

from tests.utils.system import System

pytestmark = pytest.mark.browser

PHONE = {"width": 390, "height": 844}

#: The bounding boxes of a figure's tick labels on one axis, left to right (or top to bottom).
TICK_BOXES = """([sel, axis]) => [...document.querySelectorAll(`${sel} .${axis}tick text`)]
  .map(t => t.getBoundingClientRect()).filter(r => r.width > 0)
  .map(r => ({l: r.left, r: r.right, t: r.top, b: r.bottom}))"""


def no_overlap(boxes: list[dict[str, float]], along: str) -> bool:
    lo, hi = ("l", "r") if along == "x" else ("t", "b")
    boxes = sorted(boxes, key=lambda b: b[lo])
    return all(a[hi] <= b[lo] + 0.5 for a, b in itertools.pairwise(boxes))


def drawn(page: Any, sel: str) -> None:
    page.wait_for_function(f"() => document.querySelector('{sel}')?.dataset.drawn === '1'", timeout=60_000)


def plot_height(page: Any, sel: str) -> float:
    return page.evaluate(f"() => document.querySelector('{sel}')._fullLayout._size.h")


def test_the_pages_at_a_phones_width(
    page: Any, system: System, dive_with_data: dict[str, Any], artifacts: Path
) -> None:
    page.set_viewport_size(PHONE)

    # Live: λ_att figures tall enough to read; the date in the axis title, not under the ticks.
    page.goto(system.url("/"))
    page.wait_for_function(
        "() => (document.querySelector('#att-depth')?.data || []).some(t => t.error_x && t.x.length)",
        timeout=90_000,
    )
    for sel in ("#att-time", "#att-depth"):
        assert plot_height(page, sel) >= 200, f"{sel}: {plot_height(page, sel)} px of plot"
    ticks = page.evaluate("() => document.querySelector('#att-time .xaxislayer-above').textContent")
    title = page.evaluate("() => document.querySelector('#att-time')._fullLayout.xaxis.title.text")
    assert not re.search(r"20\d\d", ticks), f"a date among the time ticks: {ticks!r}"
    assert title.startswith("time (UTC, 20"), title
    # Every stop that holds a point has its depth on the axis.
    depths, ticks_m = page.evaluate(
        """() => { const d = document.querySelector('#att-depth');
                   const pts = d.data.filter(t => t.error_x).flatMap(t => t.y);
                   return [pts, d._fullLayout.yaxis._vals.map(v => v.x)]; }"""
    )
    for depth in depths:
        assert min(abs(depth - t) for t in ticks_m) <= 50, (depth, ticks_m)
    page.locator("#attenuation-panel").screenshot(path=artifacts / "phone-live-lambda.png")

    # Review, timeline: LRM-A's frames drawn over LRM-B's, whose markers are hollow.
    page.goto(system.url("/review"))
    drawn(page, "#timeline")
    order = page.evaluate(
        """() => document.querySelector('#timeline').data
                 .map((t, i) => [t.name, i, t.marker?.symbol || '']).filter(([n]) => /^frames/.test(n))"""
    )
    by_name = {name: (i, symbol) for name, i, symbol in order}
    assert by_name["frames LRM-A"][0] > by_name["frames LRM-B"][0], order
    assert "open" in by_name["frames LRM-B"][1], order
    assert plot_height(page, "#timeline") >= 200

    # Frame detail: the legend under the radial profile, off its data.
    page.locator("#frames-table tbody tr[data-frame-id]").nth(2).click()
    drawn(page, "#profile-plot")
    legend, area = page.evaluate(
        """() => { const d = document.querySelector('#profile-plot');
                   const r = (e) => { const b = e.getBoundingClientRect(); return {t: b.top, b: b.bottom}; };
                   return [r(d.querySelector('.legend')), r(d.querySelector('.nsewdrag'))]; }"""
    )
    assert legend["t"] >= area["b"] or legend["b"] <= area["t"], (legend, area)
    page.locator("#frame-detail").screenshot(path=artifacts / "phone-frame-detail.png")

    # λ_att tab: the span selector inside its card.
    page.click(".tabs [data-tab=attenuation]")
    page.wait_for_selector(".span-control select")
    inside = page.evaluate(
        """() => { const s = document.querySelector('.span-control select');
                   const card = s.closest('.panel').getBoundingClientRect();
                   return s.getBoundingClientRect().right <= card.right; }"""
    )
    assert inside, "the span selector runs out of its card"

    # Linearity: no tick label runs into another.
    page.click(".tabs [data-tab=linearity]")
    for sweep in ("exposure", "gain"):
        sel = f"#lin-A-{sweep}"
        drawn(page, sel)
        assert no_overlap(page.evaluate(TICK_BOXES, [sel, "x"]), "x"), f"{sel}: x tick labels overlap"
        assert no_overlap(page.evaluate(TICK_BOXES, [sel, "y"]), "y"), f"{sel}: y tick labels overlap"
    page.screenshot(path=artifacts / "phone-review-linearity.png", full_page=True)
