"""The whole dive's λ_att through the API: a table per depth band, each pair with its depth
(`tests/ingest/test_spans.py` has the rules)."""

from __future__ import annotations

from fastapi.testclient import TestClient


def test_the_whole_dive_through_the_api_names_its_depths(client: TestClient) -> None:
    """The shared simulated dive: test stops at 1200 and 2021 m, the station at 3420 m."""
    d = client.get("/api/dives").json()[0]
    table = client.get(f"/api/dives/{d['id']}/attenuation", params={"depth_min_m": 0}).json()
    depths = [round(b["depth_m"]) for b in table["bands"]]
    assert len(depths) >= 2 and max(depths) > 3300 and min(depths) < 2200, depths
    for band in table["bands"]:
        for row in band["rows"]:
            assert {round(p["depth_m"]) for p in row["pairs"]} == {round(band["depth_m"])}
    crossing = 0
    for row in table["rows"]:
        assert all(p["depth_m"] is not None for p in row["pairs"])
        if len({round(p["depth_m"]) for p in row["pairs"]}) > 1:  # pairs of several depths: said so
            crossing += 1
            assert "depths whose" in row["note"], row["note"]
    assert crossing >= 1
    station = client.get(f"/api/dives/{d['id']}/attenuation").json()
    assert station["bands"] == [] and all(p["depth_m"] > 3300 for r in station["rows"] for p in r["pairs"])
