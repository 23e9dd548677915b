"""``camcal fit --dive`` and ``camcal report`` on a real simulated dive.

The report must be ONE file that needs nothing from anywhere (it is carried
on a USB stick and sent by e-mail), hold every section and the numbers the
API serves, and render in a browser with the network cut off.
"""

from __future__ import annotations

import json
import math
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core import __version__
from camcal.report import SECTIONS
from server.app import create_app
from server.settings import ServerSettings
from storage import queries
from storage.store import Store
from tests.utils.dive_store import copy_data

ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"


def run(*args: str) -> tuple[int, str]:
    result = CliRunner().invoke(app, [str(a) for a in args])
    return result.exit_code, result.output


@pytest.fixture(scope="module")
def dive(
    dive_data: tuple[Path, dict[str, object]], tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Any]:
    """A copy of the shared dive (the fit writes to it), its name and the API's λ_att table."""
    data = copy_data(dive_data[0], tmp_path_factory.mktemp("report") / "data")
    store = Store.open(data)
    try:
        with store.read() as s:
            d = queries.dives(s)[0]
        # An alarm whose text must be escaped, not run.
        store.raise_alarm("tilt:A", "tilt", "MAJOR", "module A tilted 7.2° <script>alert(1)</script>", "A")
    finally:
        store.close()
    with TestClient(create_app(ServerSettings(data_dir=data, events=None))) as client:
        table = client.get(f"/api/dives/{d['id']}/attenuation").json()
    return {"data": data, "name": d["name"], "id": d["id"], "table": table}


@pytest.fixture(scope="module")
def reports(dive: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """A report before any fit, the fit of one wavelength kept in the store, and the report after it."""
    out = tmp_path_factory.mktemp("reports")
    data, name = dive["data"], dive["name"]
    code, before_text = run("report", name, "--data", data, "--out", out / "before.html")
    assert code == 0, before_text
    fit_json = out / "fit.json"
    code, fit_text = run(
        "fit", "--dive", name, "--data", data, "--wavelength", "460", "--photons", "20000",
        "--sca-nodes", "55,90", "--templates", "monte-carlo", "--cache-dir", out / "templates",
        "--workers", "2", "--quiet",
        "--no-systematics", "--json", fit_json,
    )  # fmt: skip
    assert code == 0, fit_text
    code, after_text = run("report", name, "--data", data, "--out", out / "report.html")
    assert code == 0, after_text
    return {
        "before": (out / "before.html").read_text(encoding="utf-8"),
        "after_path": out / "report.html",
        "after": (out / "report.html").read_text(encoding="utf-8"),
        "after_text": after_text,
        "fit_text": fit_text,
        "fit": json.loads(fit_json.read_text()),
    }


def test_fit_of_a_stored_dive_is_reported_and_kept(dive: dict[str, Any], reports: dict[str, Any]) -> None:
    doc = reports["fit"]
    assert "kept as fit" in reports["fit_text"] and "460" in reports["fit_text"]
    (f,) = doc["fits"]
    assert f["wavelength_nm"] == 460
    for key in ("lambda_abs_m", "lambda_abs_err_m", "lambda_sca_m", "lambda_sca_err_m", "lambda_att_fit_m"):
        assert f[key] is not None and math.isfinite(f[key]) and f[key] > 0, key
    # Checked against the I_center λ_att of the same frames, which is the API's station value.
    api = {r["wavelength_nm"]: r for r in dive["table"]["rows"]}[460]
    assert f["lambda_att_icenter_m"] == pytest.approx(api["lambda_att_m"], rel=0.03)
    assert f["att_check_z"] is not None
    # The station span, as the API's table uses it, and where the inputs came from.
    inputs = doc["inputs"]
    assert inputs["dive"]["name"] == dive["name"]
    assert inputs["span"]["depth_min_m"] == pytest.approx(dive["table"]["span"]["depth_min_m"])
    assert inputs["span"]["n_frames"] == dive["table"]["span"]["n_frames"]
    assert inputs["run"]["kind"] == "live"
    assert doc["software"]["version"] == __version__
    assert len(f["contour"]["lambda_abs_m"]) == len(f["contour"]["delta_chi2"][0])
    # Kept in the store, with the same document.
    store = Store.open(dive["data"])
    try:
        with store.read() as s:
            kept = queries.latest_chisq_fit(s, dive["id"])
    finally:
        store.close()
    assert kept is not None and kept["result"]["fits"][0]["lambda_abs_m"] == f["lambda_abs_m"]
    assert kept["span"]["n_frames"] == inputs["span"]["n_frames"]
    # And the API serves it.
    with TestClient(create_app(ServerSettings(data_dir=dive["data"], events=None))) as client:
        listed = client.get(f"/api/dives/{dive['id']}/fits").json()
        latest = client.get(f"/api/dives/{dive['id']}/fits/latest").json()
    assert [x["id"] for x in listed] == [kept["id"]] and "result" not in listed[0]
    assert latest["result"]["fits"][0]["lambda_sca_m"] == f["lambda_sca_m"]


def test_fit_of_a_stored_dive_refuses_in_one_line(dive: dict[str, Any], tmp_path: Path) -> None:
    data = dive["data"]
    code, out = run("fit", "--dive", "no-such-dive", "--data", data, "--quiet", "--no-store")
    assert code == 2 and "no dive named 'no-such-dive'" in out and "Traceback" not in out
    code, out = run("fit", "--dive", dive["name"], "--data", data, "--wavelength", "999", "--quiet")
    assert code == 2 and "no frames at 999 nm" in out
    code, out = run("fit", str(tmp_path), "--dive", dive["name"], "--data", data)
    assert code == 2 and "one of them" in out
    code, out = run("fit", "--dive", dive["name"], "--data", data, "--depth-min", "9000", "--quiet")
    assert code == 2 and "no analysed frame in the span" in out


def test_report_is_one_self_contained_file(reports: dict[str, Any]) -> None:
    for page in (reports["before"], reports["after"]):
        # Nothing to load: no scripts, style sheets, frames, fonts or remote images.
        assert not re.search(r"<(script|link|iframe|object|embed)\b", page, re.I)
        assert not re.search(r"@import|url\(", page, re.I)
        for attr in re.findall(r"""\b(?:src|href|srcset|poster|data)\s*=\s*["']([^"']*)""", page, re.I):
            assert attr.startswith(("data:image/png;base64,", "#")), attr[:80]
        assert not re.search(r"https?://", page)
        assert page.count("<img ") >= 5
    assert reports["after_path"].stat().st_size < 5_000_000


def test_report_has_every_section_and_the_numbers(dive: dict[str, Any], reports: dict[str, Any]) -> None:
    page = reports["after"]
    for sid, _ in SECTIONS:
        assert f'<section id="{sid}">' in page and f'href="#{sid}"' in page, sid
    sections = dict(re.findall(r'<section id="([^"]+)">(.*?)</section>', page, re.S))
    # λ_att per wavelength with its statistical and systematic errors: the API's numbers.
    rows = dive["table"]["rows"]
    assert 460 in {r["wavelength_nm"] for r in rows}  # 405 and 525 too, unless a short dive missed one
    for r in rows:
        for key in ("lambda_att_m", "stat_err_m", "sys_err_m"):
            assert f">{r[key]:.2f}<" in sections["attenuation"], (r["wavelength_nm"], key)
    # λ_abs and λ_sca of the kept fit, with their errors, and the contour figure.
    (f,) = reports["fit"]["fits"]
    fit_section = sections["absorption-scattering"]
    assert f"{f['lambda_abs_m']:.2f} ± {f['lambda_abs_err_m']:.2f}" in fit_section
    assert f"{f['lambda_sca_m']:.2f} ± {f['lambda_sca_err_m']:.2f}" in fit_section
    assert "chi-square contours" in fit_section and "No χ² fit" not in fit_section
    # Calibration inputs, quality, linearity, attitude and the software version.
    for text in ("21.56", "41.62", "1.270", "0.040", "gray 5 to 240"):
        assert text in sections["calibration"], text
    store = Store.open(dive["data"])
    try:
        with store.read() as s:
            counts = queries.quality_counts(s, queries.live_run_id(s, dive["id"]) or -1)
    finally:
        store.close()
    for module, by_reason in counts.items():
        cells = "".join(f'<td class="num">{by_reason.get(r, 0)}</td>' for r in sorted(by_reason))
        assert f'<td class="text">{module}</td>' in sections["quality"]
        assert f'<td class="num">{sum(by_reason.values())}</td>' in sections["quality"], cells
        for reason in by_reason:
            assert ("accepted" if reason == "ok" else reason) in sections["quality"]
    assert "R²" in sections["linearity"] and "knee" in sections["linearity"]
    assert "heave period" in sections["attitude"] and "tilt" in sections["attitude"]
    assert "depth over time" in sections["timeline"]
    assert "module A tilted 7.2° &lt;script&gt;" in sections["timeline"] and "still active" in page
    assert f"camcal {__version__}" in sections["software"]


def test_report_without_a_fit_says_how_to_make_one(dive: dict[str, Any], reports: dict[str, Any]) -> None:
    page = reports["before"]
    assert "No χ² fit has been kept" in page
    assert f"camcal fit --dive {dive['name']} --data {dive['data']}" in page


def test_report_of_an_unknown_dive_is_refused(dive: dict[str, Any], tmp_path: Path) -> None:
    code, out = run("report", "nope", "--data", dive["data"], "--out", tmp_path / "r.html")
    assert code == 2 and "no dive named 'nope'" in out and not (tmp_path / "r.html").exists()
    code, out = run("report", "nope", "--data", tmp_path / "empty")
    assert code == 2 and "no camcal store" in out


def test_report_onto_a_full_disk_is_one_line_and_leaves_nothing(tmp_path: Path) -> None:
    """A USB stick with 4 kB left (an empty dive's report needs 8): one line that says what to do, exit 1
    (a disk, not a wrong option: was exit 2 with a bare errno), and no partial file."""
    import shutil

    from tests.utils.tmpfs import small_tmpfs

    store = Store.open(tmp_path / "data")
    try:
        dive = store.create_dive("a-dive")
        store.analysis_run(dive.id, "live", software_version=__version__)
    finally:
        store.close()
    with small_tmpfs(tmp_path / "usb", 1) as usb:
        (usb / "filler").write_bytes(b"\0" * (shutil.disk_usage(usb).free - 4 * 1024))
        code, out = run("report", "a-dive", "--data", tmp_path / "data", "--out", usb / "r.html")
        assert code == 1, out
        assert f"cannot write the report to {usb / 'r.html'}" in " ".join(out.split()) and "free space" in out
        assert sorted(p.name for p in usb.iterdir()) == ["filler"]


def test_report_of_a_dive_without_data_says_so(tmp_path: Path) -> None:
    store = Store.open(tmp_path / "data")
    try:
        dive = store.create_dive("empty-dive")
        code, out = run("report", "empty-dive", "--data", tmp_path / "data", "--out", tmp_path / "r.html")
        assert code == 2 and "has no analysis run yet" in out
        store.analysis_run(dive.id, "live", software_version=__version__)
    finally:
        store.close()
    code, out = run("report", "empty-dive", "--data", tmp_path / "data", "--out", tmp_path / "r.html")
    assert code == 0, out
    page = (tmp_path / "r.html").read_text(encoding="utf-8")
    for sid, _ in SECTIONS:
        assert f'<section id="{sid}">' in page
    assert "No frame and no sensor sample" in page and "No χ² fit has been kept" in page


@pytest.mark.browser
def test_report_renders_offline_in_a_browser(reports: dict[str, Any], tmp_path: Path, browser: Any) -> None:
    # Opened from a folder of its own, like a file on a USB stick.
    stick = tmp_path / "usb"
    stick.mkdir()
    page_file = Path(shutil.copy(reports["after_path"], stick / "dive-report.html"))
    blocked: list[str] = []

    def only_the_file(route: Any) -> None:
        url = route.request.url
        if url.startswith(("file:", "data:")):
            route.continue_()
        else:
            blocked.append(url)
            route.abort()

    ARTIFACTS.mkdir(exist_ok=True)
    context = browser.new_context(viewport={"width": 1100, "height": 900}, offline=True)
    try:
        page = context.new_page()
        page.route("**/*", only_the_file)
        page.goto(page_file.as_uri())
        page.wait_for_load_state("load")
        widths = page.evaluate("Array.from(document.images).map(i => i.complete ? i.naturalWidth : 0)")
        headings = page.locator("h2").all_inner_texts()
        page.locator("#absorption-scattering").screenshot(path=str(ARTIFACTS / "report-fit.png"))
        page.screenshot(path=str(ARTIFACTS / "report.png"), full_page=True)
    finally:
        context.close()
    assert blocked == []
    assert widths and all(w > 300 for w in widths), widths
    assert headings == [title for _, title in SECTIONS]
