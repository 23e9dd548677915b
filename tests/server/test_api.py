"""The REST API on a store filled by a real simulated dive."""

from __future__ import annotations

import math
import re

import pytest
from fastapi.testclient import TestClient

from camcal.core.passplan import plan_pass
from camcal.core.schedule import Schedule
from tests.server.conftest import TOKEN


def test_dives_and_timeline(client: TestClient, dive_data) -> None:
    _, info = dive_data
    dives = client.get("/api/dives").json()
    assert len(dives) == 1
    d = dives[0]
    assert d["n_frames"] == sum(info["frames"].values()) and d["max_depth_m"] > 3300
    tl = client.get(f"/api/dives/{d['id']}/timeline").json()
    assert len(tl["depth"]["t_unix_s"]) > 10 and max(tl["depth"]["depth_m"]) > 3300
    assert len(tl["frames"]) >= 10
    # each module's own depth: B hangs ~20 m above A (one series of both zigzagged between them)
    by = tl["depth_by_module"]
    assert set(by) == {"A", "B"}, set(by)
    assert max(by["A"]["depth_m"]) - max(by["B"]["depth_m"]) == pytest.approx(20.06, abs=3.0)
    assert client.get("/api/dives/999").status_code == 404


def test_a_dive_without_a_kept_fit(client: TestClient) -> None:
    dive_id = client.get("/api/dives").json()[0]["id"]
    assert client.get(f"/api/dives/{dive_id}/fits").json() == []
    r = client.get(f"/api/dives/{dive_id}/fits/latest")
    assert r.status_code == 404 and "camcal fit --dive" in r.json()["error"]["message"]
    assert client.get("/api/dives/999/fits").status_code == 404


def test_frames_filter_and_page(client: TestClient) -> None:
    page = client.get("/api/frames", params={"limit": 5}).json()
    assert page["limit"] == 5 and len(page["items"]) == 5 and page["total"] > 20
    total = page["total"]
    only_a = client.get("/api/frames", params={"module": "A", "limit": 500}).json()
    assert 0 < only_a["total"] < total and {f["module"] for f in only_a["items"]} == {"A"}
    ok = client.get("/api/frames", params={"status": "ok", "wavelength_nm": 460, "limit": 500}).json()
    assert all(f["status"] == "ok" and f["wavelength_nm"] == 460 for f in ok["items"])
    deep = client.get("/api/frames", params={"depth_min_m": 3300, "limit": 500}).json()
    assert all(f["depth_m"] >= 3300 for f in deep["items"])
    times = [f["captured_unix_s"] for f in client.get("/api/frames", params={"limit": 50}).json()["items"]]
    assert times == sorted(times)
    second = client.get("/api/frames", params={"limit": 5, "offset": 5}).json()["items"]
    assert {f["id"] for f in second}.isdisjoint({f["id"] for f in page["items"]})
    bad = client.get("/api/frames", params={"status": "maybe"})
    assert bad.status_code == 422 and bad.json()["error"]["code"] == "invalid"
    assert "status" in bad.json()["error"]["message"]


def test_frame_analysis_thumbnail_and_image(client: TestClient) -> None:
    f = client.get("/api/frames", params={"status": "ok", "limit": 1}).json()["items"][0]
    full = client.get(f"/api/frames/{f['id']}").json()
    assert full["profile"]["mean_gray"] and full["fit"]["background_gray"] > 0
    assert full["i_center_gray"] == pytest.approx(full["center_gray"] - full["background_gray"], abs=1e-3)
    an = client.get(f"/api/frames/{f['id']}/analysis").json()
    assert len(an["centroid_px"]) == 2 and an["radius_px"] > 10
    thumb = client.get(f["thumbnail_url"])
    assert thumb.status_code == 200 and thumb.headers["content-type"] == "image/jpeg"
    assert thumb.content[:2] == b"\xff\xd8"
    img = client.get(f["image_url"])
    assert img.status_code == 200 and img.content[:4] == b"\x89PNG"
    assert client.get("/api/frames/0/thumbnail").json()["error"]["code"] == "not_found"


def test_sensors_and_attitude_are_downsampled_for_long_ranges(client: TestClient) -> None:
    s = client.get("/api/sensors", params={"module": "A", "max_points": 50}).json()
    assert s["downsampled"] and len(s["t_unix_s"]) <= 51 and s["n_samples"] > 500
    assert min(s["temperature_c"]) > -5 and max(s["depth_m"]) > 3300
    assert len(s["temperature_c_min"]) == len(s["t_unix_s"])
    fine = client.get(
        "/api/sensors",
        params={"module": "A", "max_points": 20000, "t_from": s["t_unix_s"][10], "t_to": s["t_unix_s"][12]},
    ).json()
    assert not fine["downsampled"] and len(fine["t_unix_s"]) > 2
    att = client.get("/api/attitude", params={"module": "B", "max_points": 100}).json()
    assert att["n_samples"] > 5 and all(0 <= t < 10 for t in att["tilt_deg"])
    periods = [p for p in att["heave_period_s"] if p]
    assert periods and 4.0 < sorted(periods)[len(periods) // 2] < 11.0


def test_attenuation_series_and_table_match_the_water(client: TestClient, dive_data) -> None:
    _, info = dive_data
    sim = info["sim"]
    series = client.get("/api/attenuation").json()["series"]
    assert set(series) == {"405", "460", "525"}
    d = client.get("/api/dives").json()[0]
    table = client.get(f"/api/dives/{d['id']}/attenuation").json()
    rows = {r["wavelength_nm"]: r for r in table["rows"]}
    assert set(rows) == {405, 460, 525}
    station = sim.profile.window("station")
    mid = 0.5 * (station[0] + station[1])
    for wl, r in rows.items():
        truth = sim.lambda_att_pair_truth_m(wl, mid)
        assert r["lambda_att_m"] == pytest.approx(truth, rel=0.05)
        assert r["stat_err_m"] > 0 and r["sys_err_m"] > 0 and r["n_pairs"] >= 1
        assert math.isclose(r["total_err_m"], math.hypot(r["stat_err_m"], r["sys_err_m"]))


def test_linearity_alarms_health_and_audit(client: TestClient) -> None:
    lin = client.get("/api/linearity").json()
    assert lin["checks"], "no linearity fit"
    assert all(c["r2"] > 0.98 for c in lin["checks"] if c["sweep"] == "exposure")
    assert isinstance(client.get("/api/alarms").json(), list)
    h = client.get("/api/health").json()
    assert h["ingest"]["up"] is False and set(h["modules"]) == {"A", "B"}
    assert h["modules"]["A"]["link"] == "unknown"
    assert isinstance(client.get("/api/audit").json(), list)


def test_export_zip(client: TestClient) -> None:
    import io
    import zipfile

    d = client.get("/api/dives").json()[0]
    for fmt in ("csv", "parquet"):
        r = client.get(f"/api/dives/{d['id']}/export", params={"format": fmt})
        assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
        names = zipfile.ZipFile(io.BytesIO(r.content)).namelist()
        assert f"frames.{fmt}" in names and f"sensor_samples.{fmt}" in names
    assert client.get(f"/api/dives/{d['id']}/export", params={"format": "xls"}).status_code == 422


def test_operator_actions_need_a_valid_token(client: TestClient) -> None:
    d = client.get("/api/dives").json()[0]
    url = f"/api/dives/{d['id']}/reanalyses"
    r = client.post(url, json={"label": "x"})
    assert r.status_code == 401 and r.json()["error"]["code"] == "unauthorized"
    r = client.post(url, json={"label": "x"}, headers={"Authorization": "Bearer wrong-token-xx"})
    assert r.status_code == 403 and r.json()["error"]["code"] == "forbidden"
    r = client.post("/api/alarms/999999/ack", headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 404


def test_unknown_routes_and_methods_use_the_error_shape(client: TestClient) -> None:
    r = client.get("/api/nothing-here")
    assert r.status_code == 404 and set(r.json()) == {"error"} and r.json()["error"]["code"] == "not_found"
    r = client.delete("/api/dives")
    assert r.status_code == 405 and r.json()["error"]["code"] == "method_not_allowed"


@pytest.mark.parametrize(
    "path",
    [
        "/static/../server/app.py",
        "/static/%2e%2e/%2e%2e/etc/passwd",
        "/static/..%2f..%2fcamcal.db",
        "/vendor/../../etc/passwd",
    ],
)
def test_path_traversal_is_refused(client: TestClient, path: str) -> None:
    r = client.get(path)
    assert r.status_code in (400, 404)
    assert b"root:" not in r.content and b"create_app" not in r.content


def test_every_sheet_of_the_stylesheet_index_is_served(client: TestClient) -> None:
    """The pages link camcal.css, which imports the sheets: a sheet it names and the server lacks
    would leave a page unstyled with no error anywhere but the browser's console."""
    index = client.get("/static/css/camcal.css")
    assert index.status_code == 200
    sheets = re.findall(r'@import url\("([\w.-]+\.css)"\)', index.text)
    assert len(sheets) >= 5 and "base.css" in sheets
    for name in sheets:
        r = client.get(f"/static/css/{name}")
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/css"), name
        assert "{" in r.text and "@import" not in r.text, name  # rules, and no second level of imports


def test_plotly_is_served_locally_and_compressed(client: TestClient) -> None:
    r = client.get("/vendor/plotly.min.js", headers={"Accept-Encoding": "gzip"})
    assert r.status_code == 200 and r.headers["content-encoding"] == "gzip"
    assert len(r.content) > 1_000_000 and b"plotly" in r.content[:5000].lower()
    assert (
        client.get("/docs").status_code == 200
        and client.get("/openapi.json").json()["info"]["title"] == "camcal"
    )


def test_presets_estimate_one_pass_as_the_preview_does(client) -> None:
    presets = client.get("/api/schedules/presets").json()
    assert {"trex", "linearity-scan"} <= set(presets)
    estimate = ("n_frames", "pass_duration_s", "busy_share", "turns_per_pass", "lem_dwell_s", "warnings")
    for name, p in presets.items():
        schedule = {k: v for k, v in p.items() if k not in estimate}
        preview = client.post("/api/schedules/preview", json={"schedule": schedule}).json()
        same = [k for k in estimate if k != "warnings"]
        assert {k: p[k] for k in same} == {k: preview[k] for k in same}, name
        # the preview adds what the frames seen so far predict (a wavelength with no usable setting)
        assert preview["warnings"][: len(p["warnings"])] == p["warnings"], name
        plan = plan_pass(Schedule.model_validate(schedule), 0.8, 60.0)  # the app's readout and LEM dwell
        assert p["pass_duration_s"] == round(plan.duration_s, 1) >= round(plan.shooting_s, 1), name
    # T-REX's full grid: 25 min of shots a colour against the LEM's 60 s, spread over ~25 turns, said so
    trex = presets["trex"]
    assert all(24 <= n <= 27 for n in trex["turns_per_pass"].values()) and trex["busy_share"] > 0.95
    assert "several turns" in trex["warnings"][0] and not presets["quick-check"]["warnings"]


def test_schedule_validation_names_the_value_and_drops_pydantics_prefix(client) -> None:
    """An operator typing "0.1, abc" read "Input should be a valid number, unable to parse string as a
    number" (which of them?), and a pass too large read "Value error, one pass would take ...\""""
    base = {"name": "x", "exposures_s": [0.1, "abc"], "gains_db": [6.0]}
    r = client.post("/api/schedules/preview", json={"schedule": base})
    assert r.status_code == 422
    (problem,) = r.json()["error"]["detail"]
    assert problem["field"] == "schedule.exposures_s.1" and problem["reason"].endswith("(got 'abc')"), problem
    huge = {**base, "exposures_s": [0.1 * k for k in range(1, 61)], "gains_db": [float(g) for g in range(40)]}
    r = client.post("/api/schedules/preview", json={"schedule": {**huge, "repeats": 10}})
    reason = r.json()["error"]["detail"][0]["reason"]
    assert reason.startswith("one pass would take 72000 frames"), reason


def test_a_filter_naming_what_does_not_exist_is_refused_not_answered_as_empty(client) -> None:
    """Each of these answered 200 as if nothing matched (or, for a frame's analysis, "pending")."""
    frame_id = client.get("/api/frames?limit=1").json()["items"][0]["id"]
    dive_id = client.get("/api/dives").json()[0]["id"]
    for url, says in (
        ("/api/frames?run=999", "no analysis run 999"),
        (f"/api/frames/{frame_id}/analysis?run=999", "no analysis run 999"),
        (f"/api/frames?dive={dive_id + 50}", f"no dive {dive_id + 50}"),
        (f"/api/attenuation?dive={dive_id + 50}", f"no dive {dive_id + 50}"),
        (f"/api/linearity?run=999&dive={dive_id}", "no analysis run 999"),
    ):
        r = client.get(url)
        assert r.status_code == 404 and says in r.json()["error"]["message"], (url, r.text)
    assert client.get("/api/commands?state=bogus").status_code == 422
    assert client.get("/api/commands?state=done").status_code == 200
    r = client.get("/api/frames?depth_min_m=5000&depth_max_m=10")
    assert r.status_code == 422 and "swap them" in r.json()["error"]["message"]
    live = client.get(f"/api/frames?dive={dive_id}&limit=1").json()  # what exists still answers
    assert live["total"] > 0


def test_a_span_that_cuts_one_module_out_says_why_it_has_no_lambda(client) -> None:
    """The modules hang ~20 m apart: a depth range around the deeper one held its frames alone and
    answered "no λ_att in this span" with nothing to say why."""
    d = client.get("/api/dives").json()[0]
    station = client.get(f"/api/dives/{d['id']}/attenuation").json()
    assert station["rows"] and "note" not in station["span"]
    deep = client.get(
        f"/api/dives/{d['id']}/attenuation", params={"depth_min_m": d["max_depth_m"] - 5.0}
    ).json()
    assert deep["span"]["n_frames"] > 0 and not [r for r in deep["rows"] if r["lambda_att_m"]]
    assert "frames of A only" in deep["span"]["note"] and "widen it" in deep["span"]["note"], deep["span"]
