"""The dive's state, the latest frame and λ_att, and the depths of a span, as the pages show them:
its own ``camcal serve`` of the shared simulated dive (which ended: the modules came back on deck and
signed off), in Debian's Chromium at desk, tablet and phone widths.

Seen on deck: a finished dive stayed "open"; after a restart the live cards kept the previous run's
thumbnails and λ_att as "latest" (the largest capture time, a module clock that ran ahead) while new
frames arrived; the whole-dive λ_att pooled three depths without showing them.
"""

from __future__ import annotations

import itertools
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest
from sqlalchemy import func, select

from storage import queries
from storage.models import AttenuationPoint, Frame, FrameResult
from storage.store import FrameRow, Store
from tests.browser.conftest import camcal_page
from tests.utils.dive_store import copy_data
from tests.utils.system import camcal_serve

pytestmark = pytest.mark.browser

WIDTHS = {"desk": 1440, "tablet": 820, "phone": 390}


def receive_late(data: Path) -> tuple[int, float, dict[str, Any]]:
    """A frame of module A (with its result) and a λ_att point at 460 nm received after everything
    else, both stamped an hour before the dive's first frame: a restarted module whose clock reads
    earlier than the previous run's (a simulation's ran ahead at 10x). Their ids and the point's value."""
    store = Store.open(data)
    try:
        with store.read() as s:
            dive = queries.dives(s)[0]
            run = queries.live_run_id(s, dive["id"])
            fr, res = s.execute(
                select(Frame, FrameResult)
                .join(FrameResult, FrameResult.frame_id == Frame.id)
                .where(Frame.module_id == "A", FrameResult.status == "ok", FrameResult.run_id == run)
                .limit(1)
            ).one()
            point = s.scalars(
                select(AttenuationPoint).where(
                    AttenuationPoint.run_id == run, AttenuationPoint.wavelength_nm == 460
                )
            ).first()
            t0 = s.scalar(select(func.min(Frame.captured_unix_s)).where(Frame.dive_id == dive["id"]))
            frame_row = {c: getattr(fr, c) for c in FrameRow.__dataclass_fields__ if c != "dive_id"}
            result_row = {c.name: getattr(res, c.name) for c in FrameResult.__table__.columns}
            point_row = {c.name: getattr(point, c.name) for c in AttenuationPoint.__table__.columns}
        early = t0 - 3600.0
        row = FrameRow(**{**frame_row, "boot": "restarted", "seq": 1, "captured_unix_s": early})
        row.received_unix_s = time.time()
        row.captured_ship_unix_s = row.received_unix_s - 1.0  # its clock as the ship mapped it
        frame_id = store.commit_batch(dive["id"], [row]).new_frames[("A", "restarted", 1)]
        store.save_results(
            run,
            [{**{k: v for k, v in result_row.items() if k not in ("id", "run_id")}, "frame_id": frame_id}],
        )
        value = round(point_row["lambda_att_m"] + 3.21, 2)  # told apart from every other point
        store.add_attenuation_points(
            [
                {
                    **{k: v for k, v in point_row.items() if k != "id"},
                    "t_unix_s": early,
                    "visit_key": "restarted-460",
                    "lambda_att_m": value,
                    "final": True,
                }
            ]
        )
        return frame_id, value, dive
    finally:
        store.close()


def receipts(data: Path) -> dict[int, tuple[str, float]]:
    """Each frame's module and when the ship received it (on the ship's clock, as alarms are)."""
    store = Store.open(data)
    try:
        with store.read() as s:
            rows = s.execute(select(Frame.id, Frame.module_id, Frame.received_unix_s))
            return {i: (m, r) for i, m, r in rows}
    finally:
        store.close()


def assert_in_the_order_received(page: Any, received: dict[int, tuple[str, float]]) -> None:
    """The timeline's events are ordered on the ship's clock: each frame mark lies at or before the
    moment the ship received that frame (captured, then received), and each module's marks come
    in the order its frames arrived (within 2 s: the mapping's offset is measured anew at every
    heartbeat). On the modules' 10x clocks the marks ran ahead of their receipt, so an alarm,
    raised on the ship's clock, was drawn among the wrong frames."""
    marks = page.evaluate(
        """() => document.querySelector('#timeline').data
            .filter((t) => t.name.startsWith('frames'))
            .flatMap((t) => t.x.map((x, i) => [t.customdata[i], Date.parse(x.replace(' ', 'T') + 'Z')]))"""
    )
    marks = [(i, ms / 1e3) for i, ms in marks]
    assert len(marks) >= 30, marks
    late = [(i, x, received[i][1]) for i, x in marks if x > received[i][1] + 1.0]  # (ms rounding)
    assert not late, f"frames drawn after they were received: {late[:5]}"
    for module in {m for m, _ in received.values()}:
        arrived = [received[i][1] for _, i in sorted((x, i) for i, x in marks if received[i][0] == module)]
        back = [(a, b) for a, b in itertools.pairwise(arrived) if b < a - 2.0]
        assert not back, f"LRM-{module}: marks drawn before frames that arrived earlier: {back[:5]}"


def test_the_pages_show_the_dive_state_the_latest_received_and_the_depths_of_a_span(
    browser: Any, dive_data: tuple[Path, dict[str, object]], tmp_path: Path, artifacts: Path
) -> None:
    data = copy_data(dive_data[0], tmp_path / "data")
    frame_id, value, dive = receive_late(data)
    received_last = time.time()  # (the late frame's; the dive's others arrived before)
    received = receipts(data)
    assert dive["state"] == "ended" and "back on deck and signed off" in dive["state_reason"], dive
    with (
        camcal_serve(data) as (url, _),
        camcal_page(browser, SimpleNamespace(base_url=url)) as page,
    ):
        for name, width in WIDTHS.items():
            page.set_viewport_size({"width": width, "height": 900})
            page.goto(f"{url}/")
            # latest = received last: the restarted module's frame and point, not the largest time
            page.wait_for_selector(f"#module-A img[data-frame-id='{frame_id}']")
            label = page.locator("#module-A [data-field='frame-label']").inner_text()
            assert label.startswith(f"#{frame_id} "), label
            now_460 = "document.querySelector('#att-now [data-wl=\"460\"] .huge')?.textContent"
            page.wait_for_function(f"{now_460}.startsWith('{value:.1f}')")
            # the dive's state, and why, on every width
            chip = page.locator("#dive-state")
            assert chip.is_visible() and chip.inner_text() == "dive ended"
            notice = page.locator("#dive-notice")
            assert notice.is_visible() and "back on deck and signed off" in notice.inner_text()
            assert "The next start of camcal up begins a new dive" in notice.inner_text()
            page.wait_for_selector("#att-time .main-svg")
            page.screenshot(path=str(artifacts / f"live-dive-ended-{name}.png"), full_page=True)

            page.goto(f"{url}/review#dive={dive['id']}&tab=attenuation")
            page.wait_for_selector("#dive-state[data-state='ended']")
            page.select_option(".span-control[data-for='attenuation'] select", "all")
            page.wait_for_selector("#att-table tr.band[data-band]")
            bands = page.locator("#att-table tr.band[data-band]").all_inner_texts()
            assert len(bands) >= 2 and all(b.startswith("LEM depth ") for b in bands), bands
            page.locator("#att-table tr.pairs summary").first.click()  # one band's pairs, with their depth
            pairs = page.locator("#att-table details[open] table").first.inner_text()
            assert pairs.startswith("LEM depth") and " m\t" in pairs, pairs
            page.wait_for_selector("#att-series-time .main-svg")
            page.screenshot(path=str(artifacts / f"review-depth-bands-{name}.png"), full_page=True)

            # One clock: the timeline draws the 10x modules' frames on the ship's clock (within what
            # the ship received), and says how each module's clock was mapped onto it.
            page.click(".tabs [data-tab='frames']")
            page.wait_for_selector("#timeline .main-svg")
            note = page.locator("#timeline-clocks").inner_text()
            assert "Times on the ship's clock" in note and "LRM-A: a simulated clock at 10×" in note, note
            frames_x = page.evaluate(
                """() => document.querySelector('#timeline').data
                    .filter((t) => t.name.startsWith('frames'))
                    .flatMap((t) => t.x.map((x) => Date.parse(x.replace(' ', 'T') + 'Z') / 1000))"""
            )
            assert frames_x and min(frames_x) >= dive["first_received_unix_s"] - 60
            assert max(frames_x) <= received_last + 1, (max(frames_x), received_last)
            assert_in_the_order_received(page, received)
            page.screenshot(path=str(artifacts / f"review-timeline-clock-{name}.png"), full_page=True)
