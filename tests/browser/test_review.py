"""The review view in a real browser: timeline and frames, λ_att, linearity, export, re-analysis, audit."""

from __future__ import annotations

import csv
import io
import re
import zipfile
from pathlib import Path
from typing import Any

import pytest

from tests.utils.system import System

pytestmark = pytest.mark.browser

DRAWN = "sel => { const d = document.querySelector(sel); return d && d.dataset.drawn === '1'; }"


def rows(page: Any) -> list[dict[str, str]]:
    return page.evaluate(
        """() => [...document.querySelectorAll('#frames-table tbody tr[data-frame-id]')].map(tr => ({
             id: tr.dataset.frameId, module: tr.children[3].textContent,
             status: tr.children[8].textContent}))"""
    )


def download_png(page: Any, plot: str) -> bytes:
    """Click plotly's 'Download plot as a PNG' (works offline: the page reaches only camcal)."""
    page.hover(plot)
    with page.expect_download() as dl:
        page.click(f"{plot} .modebar-btn[data-title='Download plot as a PNG']")
    return Path(dl.value.path()).read_bytes()


def test_review_timeline_filters_and_one_frame(
    page: Any, system: System, dive_with_data: dict[str, Any], artifacts: Path
) -> None:
    page.goto(system.url("/review"))
    page.wait_for_function(DRAWN, arg="#timeline")
    assert page.locator("#dive-select option").count() >= 1
    page.wait_for_selector("#frames-table tbody tr[data-frame-id]")
    total = int(re.search(r"of (\d+) frames", page.inner_text("#page-info")).group(1))
    assert total >= 30

    # Filter: module B, status ok.
    page.select_option("#frame-filters [name=module]", "B")
    page.select_option("#frame-filters [name=status]", "ok")
    page.wait_for_function(
        """() => { const r = [...document.querySelectorAll('#frames-table tbody tr[data-frame-id]')];
                   return r.length && r.every(tr => tr.children[3].textContent === 'B'
                                                 && tr.children[8].textContent === 'ok'); }"""
    )
    filtered = int(re.search(r"of (\d+) frames", page.inner_text("#page-info")).group(1))
    assert 0 < filtered < total
    # Paging.
    if filtered > 25:
        first = rows(page)[0]["id"]
        page.click("#page-next")
        page.wait_for_function(
            "id => document.querySelector('#frames-table tbody tr[data-frame-id]').dataset.frameId !== id",
            arg=first,
        )
        assert page.inner_text("#page-info").startswith("26–")
        page.click("#page-prev")
    page.screenshot(path=artifacts / "review-frames.png", full_page=True)

    # Click a frame mark on the timeline: the list jumps to its time and the frame opens.
    mark = page.locator("#timeline .scatterlayer .trace").nth(2).locator(".point").nth(3)
    page.locator("#timeline").scroll_into_view_if_needed()
    box = mark.bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.wait_for_selector("#frames-table tbody tr.marked")
    page.wait_for_selector("#frame-detail:not([hidden]) #frame-numbers")

    # Open an ok frame from the list: full PNG with the LEM drawn, its radial profile on a log scale.
    page.locator("#frames-table tbody tr[data-frame-id]").first.click()
    page.wait_for_function(DRAWN, arg="#profile-plot")
    page.wait_for_function(
        "() => { const i = document.getElementById('frame-image'); return i.complete && i.naturalWidth > 0; }"
    )
    assert page.evaluate("document.getElementById('profile-plot').layout.yaxis.type") == "log"
    names = page.evaluate("document.getElementById('profile-plot').data.map(t => t.name)")
    assert any(n.startswith("fit:") for n in names) and any(n.startswith("background") for n in names)
    numbers = page.inner_text("#frame-numbers")
    assert "I_center" in numbers and "background" in numbers
    assert page.locator("#frame-detail svg circle").count() == 1
    page.locator("#frame-detail").scroll_into_view_if_needed()
    page.screenshot(path=artifacts / "review-frame.png", full_page=True)
    assert download_png(page, "#profile-plot").startswith(b"\x89PNG")


def test_review_attenuation_linearity_attitude_and_export(
    page: Any, system: System, dive_with_data: dict[str, Any], artifacts: Path
) -> None:
    page.goto(system.url("/review#tab=attenuation"))
    page.wait_for_selector(".span-control[data-for=attenuation] select")
    # Early in the dive the station may hold no pairs yet: combine the whole dive.
    page.select_option(".span-control[data-for=attenuation] select", "all")
    page.wait_for_selector("#att-span:has-text('the whole dive')")
    page.wait_for_selector("#att-table tbody tr[data-wl]")
    rows = page.locator("#att-table tbody tr[data-wl]")
    whole = rows.first.locator("td").all_inner_texts()
    if whole[1] == "–":  # the dive crosses depths whose water differs: no one value, one per depth
        assert "whose water differs" in whole[-1], whole
        rows = page.locator("#att-table tbody tr[data-wl][data-depth]")
    cells = rows.first.locator("td").all_inner_texts()
    assert re.fullmatch(r"\d+(\.\d+)?", cells[1]), cells  # λ_att
    assert re.fullmatch(r"\d+\.\d+", cells[2]) and re.fullmatch(r"\d+\.\d+", cells[3])  # stat, sys
    page.wait_for_function(DRAWN, arg="#att-series-time")
    page.wait_for_function(DRAWN, arg="#att-series-depth")
    # No χ² fit has been kept for this dive: the panel says how to make one (the fit's own table,
    # limits and budget are rendered from a kept fit; camcal fit --dive is too slow for this suite).
    page.wait_for_selector("#chisq-fit p.empty:has-text('camcal fit --dive')")
    page.screenshot(path=artifacts / "review-attenuation.png", full_page=True)

    page.click(".tabs [data-tab=linearity]")
    page.wait_for_selector("#linearity .panel[data-module]")
    page.wait_for_function("() => document.querySelectorAll('#linearity .plot[data-drawn]').length >= 2")
    r2 = page.locator("#linearity td[data-r2]").evaluate_all("n => n.map(x => Number(x.dataset.r2))")
    assert r2 and all(0 <= v <= 1 for v in r2)
    page.screenshot(path=artifacts / "review-linearity.png", full_page=True)

    page.click(".tabs [data-tab=attitude]")
    page.wait_for_function(DRAWN, arg="#attitude-plot")
    page.wait_for_function(DRAWN, arg="#housing-plot")
    page.screenshot(path=artifacts / "review-attitude.png", full_page=True)
    assert download_png(page, "#attitude-plot").startswith(b"\x89PNG")

    # Export: both links return a ZIP of tables, and the browser downloads it.
    for fmt, ext in (("csv", ".csv"), ("parquet", ".parquet")):
        href = page.get_attribute(f"#export-{fmt}", "href")
        assert href.endswith(f"format={fmt}")
        resp = page.request.get(system.url(href))
        assert resp.ok and resp.headers["content-type"] == "application/zip"
        names = zipfile.ZipFile(io.BytesIO(resp.body())).namelist()
        tables = [n for n in names if n not in ("setup.json", "run.json")]  # what the numbers came from
        assert tables and all(n.endswith(ext) for n in tables) and len(names) == len(tables) + 2, names
    with page.expect_download() as dl:
        page.click("#export-csv")
    assert dl.value.suggested_filename.endswith("-csv.zip")
    assert zipfile.is_zipfile(dl.value.path())


def test_review_reanalysis_side_by_side_and_audit(
    page: Any, system: System, dive_with_data: dict[str, Any], artifacts: Path
) -> None:
    # A stored calibration record is offered as a starting point and fills the form.
    setup = {
        "cameras": {
            "A": {"distance_m": 21.56, "distance_err_m": 0.02},
            "B": {"distance_m": 41.9, "distance_err_m": 0.05},
        },
        "emission_ratio": {"405": {"value": 1.04, "err": 0.03}},
        "linear_range": [5, 235],
    }
    resp = page.request.post(
        system.url("/api/calibrations"),
        data={"name": "browser-test", "setup": setup, "source": "test"},
        headers={"Authorization": f"Bearer {system.token}"},
    )
    assert resp.ok, resp.text()
    record = resp.json()["id"]
    page.goto(system.url("/review#tab=reanalysis"))
    page.wait_for_selector("#reanalysis-form [name='cam-B-v']")
    page.select_option("#reanalysis-form [name=from]", str(record))
    page.wait_for_function(
        "() => document.querySelector(\"#reanalysis-form [name='cam-B-v']\").value === '41.9'"
    )
    assert page.input_value("#reanalysis-form [name='lin-hi']") == "235"
    page.select_option("#reanalysis-form [name=from]", "")
    page.wait_for_function(
        "() => document.querySelector(\"#reanalysis-form [name='cam-B-v']\").value === '41.62'"
    )
    assert page.is_disabled("#reanalysis-submit")
    page.click("#login")
    page.fill("#login-token", system.token)
    page.click("#login-submit")
    page.wait_for_selector("#reanalysis-submit:enabled")

    page.select_option(".span-control[data-for=compare] select", "all")
    page.fill("#reanalysis-form [name='cam-B-v']", "41.80")
    page.fill("#reanalysis-form [name='er-460-v']", "1.30")
    page.fill("#reanalysis-form [name='label']", "B at 41.80 m, 460 nm ratio 1.30")
    page.click("#reanalysis-submit")
    run = "#runs-table tr:has-text('B at 41.80 m')"
    page.wait_for_selector(run)
    page.wait_for_selector(f"{run} .run-status[data-status='done']", timeout=90_000)
    page.wait_for_function(
        "() => document.querySelectorAll('#cmp-table tbody tr[data-wl]').length >= 1 "
        "&& !document.querySelector('#cmp-table caption')"
    )
    first = page.locator("#cmp-table tbody tr[data-wl]").first.locator("td").all_inner_texts()
    assert "±" in first[1] and "±" in first[2], first
    assert first[3] != "0.00", "a longer far distance changes λ_att"
    page.screenshot(path=artifacts / "review-reanalysis.png", full_page=True)

    # The original run is untouched: the λ_att tab still shows the live run by default.
    page.click(".tabs [data-tab=attenuation]")
    page.wait_for_selector("#att-table tbody tr[data-wl]")
    assert "live run" in page.locator("#att-run option:checked").inner_text()
    assert page.locator(".span-control[data-for=attenuation] select").input_value() == "all"
    # Shown, that run is what the export takes: its λ_att visits alone (they came mixed with the
    # live run's) and its λ_att per wavelength, the table's numbers
    new_id = page.locator("#att-run option:has-text('B at 41.80 m')").get_attribute("value")
    page.select_option("#att-run", new_id)
    page.wait_for_function(f"() => document.querySelector('#export-csv').href.endsWith('&run={new_id}')")
    assert f"run #{new_id}" in page.inner_text("#export-label")
    resp = page.request.get(system.url(page.get_attribute("#export-csv", "href")))
    exported = zipfile.ZipFile(io.BytesIO(resp.body()))
    visits = list(csv.DictReader(io.TextIOWrapper(exported.open("attenuation.csv"))))
    assert visits and {v["run_id"] for v in visits} == {new_id}
    headline = list(csv.DictReader(io.TextIOWrapper(exported.open("lambda_att.csv"))))
    assert headline and all(h["run_id"] == new_id and float(h["stat_err_m"]) > 0 for h in headline)

    page.click(".tabs [data-tab=audit]")
    page.wait_for_selector("#audit-table tbody tr:has-text('reanalysis.start')")
    assert "tester" in page.locator("#audit-table tbody tr:has-text('reanalysis.start')").first.inner_text()
    page.screenshot(path=artifacts / "review-audit.png", full_page=True)


def test_review_frame_list_fits_a_tablet_in_portrait(
    page: Any, system: System, dive_with_data: dict[str, Any], artifacts: Path
) -> None:
    """At 768 px every column that says whether a frame is good is in view, without scrolling."""
    page.set_viewport_size({"width": 768, "height": 1024})
    page.goto(system.url("/review"))
    page.wait_for_selector("#frames-table tbody tr[data-frame-id]")
    fit = page.evaluate(
        """() => { const t = document.querySelector('#frames-table');
                   const r = t.querySelector('tbody tr[data-frame-id]').children;
                   return {table: t.scrollWidth, wrap: t.parentElement.clientWidth,
                           status: r[8].getBoundingClientRect().right,
                           center: r[9].getBoundingClientRect().right,
                           time: r[2].innerText, title: r[2].title}; }"""
    )
    assert fit["table"] <= fit["wrap"], fit
    assert fit["status"] <= 768 and fit["center"] <= 768, fit
    assert re.fullmatch(r"\d\d:\d\d:\d\d", fit["time"]), fit  # the date is in the tooltip
    assert re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d on the ship's clock", fit["title"]), fit
    page.wait_for_function(DRAWN, arg="#timeline")
    page.screenshot(path=artifacts / "review-tablet-portrait.png", full_page=True)
