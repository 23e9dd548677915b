"""The live view in a real browser against the running system: cards, thumbnails, λ_att, losing the link."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest

from tests.utils.system import System

pytestmark = pytest.mark.browser

BOTH_THUMBS = """() => ['A', 'B'].every(m => {
  const img = document.querySelector(`#module-${m} .thumb img[data-frame-id]`);
  return img && img.complete && img.naturalWidth > 0;
})"""
LAMBDA_SHOWN = """() => [...document.querySelectorAll('#att-now [data-wl] .huge')]
  .some(n => /\\d/.test(n.textContent))"""


def test_live_view_shows_both_modules_thumbnails_and_lambda_att(
    page: Any, system: System, artifacts: Path
) -> None:
    page.goto(system.url("/"))
    page.wait_for_selector("#module-A")
    page.wait_for_selector("#module-B")
    page.wait_for_selector('#conn[data-state="live"]')

    page.wait_for_function(BOTH_THUMBS, timeout=90_000)
    # The detected LEM is drawn on a thumbnail: a circle in the frame's own pixel coordinates.
    page.wait_for_function("() => document.querySelector('.module-card .thumb svg circle')", timeout=60_000)
    drawn = page.evaluate(
        """() => { const c = document.querySelector('.module-card .thumb svg circle');
                   const box = c.ownerSVGElement.getAttribute('viewBox');
                   return [box, ...['cx', 'cy', 'r'].map(a => c.getAttribute(a))]; }"""
    )
    _, _, w, h = (float(v) for v in drawn[0].split())
    cx, cy, r = (float(v) for v in drawn[1:])
    assert (w, h) != (0, 0)
    assert 0 < cx < w and 0 < cy < h and 0 < r < w / 2

    page.wait_for_function(LAMBDA_SHOWN, timeout=90_000)
    page.wait_for_function("() => document.querySelector('#att-time .scatterlayer .point')", timeout=20_000)

    for m in ("A", "B"):
        card = page.locator(f"#module-{m}")
        assert "link up" in card.locator('[data-field="link"]').inner_text()
        assert re.fullmatch(r"(405|460|525) nm", card.locator('[data-field="wavelength"]').inner_text())
        assert re.fullmatch(r"\d+", card.locator('[data-field="depth"]').inner_text())
        assert card.locator('[data-field="severity"]').inner_text() in ("OK", "MINOR", "MAJOR")
        phase = card.locator('[data-field="phase"]').inner_text()
        assert phase in ("deck", "descent", "stop", "station", "ascent")
        assert re.search(r"\d", card.locator('[data-field="tilt"]').inner_text())
        assert re.search(r"\d", card.locator('[data-field="temperature"]').inner_text())
        assert card.locator('[data-field="qlegend"] [data-quality]').count() >= 1
    assert page.locator("#overall").inner_text() in ("OK", "MINOR", "MAJOR")
    # `camcal up`'s modules are simulated at 20x: the top bar says so, and its tooltip that their
    # clock is mapped onto the ship's (every time drawn on the ship's clock, as the alarms')
    sim = page.locator("#sim-note")
    assert sim.is_visible() and sim.inner_text() == "simulated dive 20×"
    assert "mapped onto the ship's" in sim.get_attribute("title")
    page.screenshot(path=artifacts / "live-desktop.png", full_page=True)

    stats = page.evaluate("window.camcal.stats")
    assert stats["firstDataAt"] is not None and stats["firstDataAt"] < 10_000

    # A reload keeps the strip of latest frames: the server's outcomes, not one tick rebuilt from the
    # newest frame (it showed a single square after every reload).
    ticks = "() => document.querySelectorAll('#module-A [data-field=recent] span').length"
    page.wait_for_function(f"() => ({ticks})() >= 25", timeout=60_000)
    page.reload()
    page.wait_for_selector('#conn[data-state="live"]')
    page.wait_for_selector("#module-A [data-field=recent] span")
    assert page.evaluate(ticks) >= 20  # frames arrive a few a second: not the strip refilled live
    assert "latest frames" in page.locator("#module-A .recent-row").inner_text()


def test_live_view_reconnects_and_marks_stale_data(page: Any, system: System, artifacts: Path) -> None:
    """Cut the WebSocket: the page says it is reconnecting, fades the stale cards, then resyncs."""
    blocked = {"on": False}

    def route(ws: Any) -> None:
        if blocked["on"]:
            ws.close()
            return
        server = ws.connect_to_server()
        blocked.setdefault("sockets", []).append((ws, server))

    page.route_web_socket(re.compile(r".*/ws/live$"), route)
    page.goto(system.url("/"))
    page.wait_for_selector('#conn[data-state="live"]')
    page.wait_for_selector("#module-A:not(.stale)", timeout=30_000)
    snapshots = page.evaluate("window.camcal.stats.snapshots")

    blocked["on"] = True
    for ws, _server in blocked["sockets"]:
        ws.close()
    page.wait_for_selector('#conn[data-state="reconnecting"]')
    page.wait_for_selector("#banner:not([hidden])")
    assert "reconnecting" in page.locator("#banner").inner_text()
    # Nothing arrives: after stale_after_s (5 s) the cards fade and say INVALID.
    page.wait_for_selector("#module-A.stale", timeout=15_000)
    # INVALID, unless a MAJOR alarm of the module outranks it
    assert page.locator('#module-A [data-field="severity"]').inner_text() in ("INVALID", "MAJOR")
    assert "INVALID" in page.locator('#module-A [data-field="stale"]').inner_text()
    page.screenshot(path=artifacts / "live-reconnecting.png", full_page=True)

    blocked["on"] = False
    page.wait_for_selector('#conn[data-state="live"]', timeout=20_000)
    page.wait_for_selector("#module-A:not(.stale)", timeout=15_000)
    resynced = page.evaluate("window.camcal.stats.snapshots")
    assert resynced > snapshots
    assert page.locator("#banner").is_hidden()

    # The server says this browser fell behind and lost something that matters: it asks for a
    # fresh snapshot on the same socket.
    page_side = blocked["sockets"][-1][0]
    page_side.send('{"type": "missed", "dropped": {"result": 3}, "resync": true}')
    page.wait_for_function("n => window.camcal.stats.snapshots > n", arg=resynced)
    assert page.evaluate("window.camcal.stats.missed")["result"] == 3


def test_live_view_on_a_tablet_with_operator_login(page: Any, system: System, artifacts: Path) -> None:
    page.set_viewport_size({"width": 768, "height": 1024})
    page.goto(system.url("/"))
    page.wait_for_selector("#module-B")
    page.wait_for_function(BOTH_THUMBS, timeout=90_000)
    a, b = page.evaluate(  # in one frame (see test_lambda_profile): a re-render cannot come between
        "() => ['#module-A', '#module-B'].map(s => document.querySelector(s).getBoundingClientRect())"
        ".map(r => ({x: r.x, y: r.y, width: r.width, height: r.height}))"
    )
    assert b["y"] >= a["y"] + a["height"] - 1, "portrait: the module cards stack"
    assert a["width"] <= 768

    # Read-only until logged in; a wrong token says why; the right one names the operator.
    assert page.locator("#operator-name").inner_text() == "read-only"
    for button in page.locator("button.ack").all():
        assert button.is_disabled()
    page.click("#login")
    page.fill("#login-token", "not-the-token")
    page.click("#login-submit")
    page.wait_for_selector("#login-error:has-text('not valid')")
    page.fill("#login-token", system.token)
    page.click("#login-submit")
    page.wait_for_selector("#operator-name:has-text('tester')")
    if page.locator("button.ack").count():
        alarm = page.locator("li.alarm", has=page.locator("button.ack")).first
        alarm_id = alarm.get_attribute("data-alarm-id")
        alarm.locator("button.ack").click()
        acked = f"li.alarm[data-alarm-id='{alarm_id}'] .meta:has-text('acknowledged by tester')"
        page.wait_for_selector(acked)
    page.wait_for_function("() => document.querySelector('#att-depth').dataset.drawn === '1'")
    page.evaluate("document.getElementById('toast')?.setAttribute('hidden', '')")
    page.screenshot(path=artifacts / "live-tablet-portrait.png", full_page=True)

    page.set_viewport_size({"width": 1024, "height": 768})
    page.wait_for_timeout(500)
    page.screenshot(path=artifacts / "live-tablet-landscape.png")
    page.click("#theme")
    page.wait_for_timeout(1500)
    assert page.evaluate("document.documentElement.dataset.theme") == "day"
    page.screenshot(path=artifacts / "live-day-theme.png", full_page=True)
    page.click("#theme")


def test_frames_saturated_by_the_schedules_design_are_not_shown_as_a_fault(page: Any, system: System) -> None:
    """`camcal up`'s modules run trex-subsampled, whose 0.5 s and 1 s exposures saturate the LEM on
    purpose: the preview predicts it. Those frames are counted apart, hatched and muted, and the
    "last frame" line says "saturated by design" in plain text; only a saturation the prediction did
    not expect keeps the fault's red."""
    page.goto(system.url("/"))
    page.wait_for_selector('#conn[data-state="live"]')
    legend = "#module-{m} [data-field='qlegend'] [data-quality='saturated_by_design']"
    page.wait_for_function(
        """() => ['A', 'B'].some(m => document.querySelector(
                 `#module-${m} [data-field='qlegend'] [data-quality='saturated_by_design']`))""",
        timeout=90_000,
    )
    m = next(m for m in ("A", "B") if page.locator(legend.format(m=m)).count())
    assert "saturated by design" in page.inner_text(legend.format(m=m))
    bg, pattern, fault = page.evaluate(
        """(m) => { const bar = document.querySelector(`#module-${m} .qbar .q-saturated_by_design`);
                    const s = getComputedStyle(bar); const probe = document.createElement('i');
                    probe.className = 'q-saturated';
                    document.body.append(probe); const red = getComputedStyle(probe).backgroundColor;
                    probe.remove(); return [s.backgroundColor, s.backgroundImage, red]; }""",
        m,
    )
    assert bg != fault and "gradient" in pattern, (bg, pattern, fault)  # hatched and muted, not the red
    # The card's last frame, when it is one of those: said, in the muted colour of a plain fact.
    status = f"#module-{m} [data-field='frame-status']"
    page.wait_for_function(
        f"() => document.querySelector(\"{status}\").textContent === 'saturated by design'", timeout=90_000
    )
    assert page.get_attribute(status, "class") == "status-expected"
    # The server counts them apart as well, for every page that asks.
    snap = page.evaluate("() => fetch('/api/live/snapshot').then(r => r.json())")
    quality = snap["modules"][m]["quality"]
    assert quality.get("saturated_by_design", 0) > quality.get("saturated", 0), quality
