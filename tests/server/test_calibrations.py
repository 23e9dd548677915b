"""Calibrations as versioned data: v1 and v2 of a dive side by side, everything audited."""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from camcal.cli import app as cli
from camcal.core.frameset import Setup
from ingest.service import IngestConfig, IngestService
from server.app import create_app
from server.settings import ServerSettings
from storage import queries
from storage.store import Store

TOKEN = "calibration-operator-1"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


@pytest.fixture
def dive_copy(dive_data, tmp_path: Path) -> Path:
    data, _ = dive_data
    copy = tmp_path / "data"
    shutil.copytree(data, copy)
    return copy


def wait_run(client: TestClient, dive_id: int, run_id: int) -> dict:
    for _ in range(600):
        run = next(r for r in client.get(f"/api/dives/{dive_id}/runs").json() if r["id"] == run_id)
        if run["status"] not in ("queued", "running"):
            return run
        time.sleep(0.1)
    raise AssertionError("re-analysis did not finish")


def test_a_dive_analysed_with_v1_then_v2_keeps_both_side_by_side(dive_copy: Path) -> None:
    app = create_app(ServerSettings(data_dir=dive_copy, events=None, operator_tokens={"lab": TOKEN}))
    v1_setup = Setup().to_json()
    v2_setup = json.loads(json.dumps(v1_setup))
    v2_setup["emission_ratio"]["460"] = {"value": 1.35, "err": 0.03}
    with TestClient(app) as client:
        r1 = client.post(
            "/api/calibrations",
            json={"name": "trex-lab", "setup": v1_setup, "source": "lab 2021"},
            headers=AUTH,
        )
        r2 = client.post(
            "/api/calibrations",
            json={"name": "trex-lab", "setup": v2_setup, "source": "re-measured"},
            headers=AUTH,
        )
        assert (r1.status_code, r2.status_code) == (201, 201)
        v1, v2 = r1.json(), r2.json()
        assert (v1["version"], v2["version"]) == (1, 2)
        assert len(client.get("/api/calibrations").json()) == 2
        assert client.post("/api/calibrations", json={"name": "x", "setup": v1_setup}).status_code == 401
        bad = client.post(
            "/api/calibrations", json={"name": "x", "setup": {"linear_range": [9, 3]}}, headers=AUTH
        )
        assert bad.status_code == 422 and "linear_range" in bad.json()["error"]["message"]

        dive = client.get("/api/dives").json()[0]
        runs = {}
        for cal in (v1, v2):
            r = client.post(
                f"/api/dives/{dive['id']}/reanalyses", json={"calibration_id": cal["id"]}, headers=AUTH
            )
            assert r.status_code == 202, r.text
            done = wait_run(client, dive["id"], r.json()["id"])
            assert done["status"] == "done" and done["calibration_id"] == cal["id"]
            assert done["label"] == f"calibration trex-lab v{cal['version']}"
            runs[cal["version"]] = done["id"]
        tables = {
            v: {
                row["wavelength_nm"]: row
                for row in client.get(f"/api/dives/{dive['id']}/attenuation", params={"run": run}).json()[
                    "rows"
                ]
            }
            for v, run in runs.items()
        }
        live = {
            row["wavelength_nm"]: row
            for row in client.get(f"/api/dives/{dive['id']}/attenuation").json()["rows"]
        }
        # Unchanged inputs: identical results. A larger I0'/I0 at 460 nm: a shorter λ, as the formula says.
        assert tables[1][405]["lambda_att_m"] == pytest.approx(live[405]["lambda_att_m"])
        assert tables[2][405]["lambda_att_m"] == pytest.approx(tables[1][405]["lambda_att_m"])
        lam1, lam2 = tables[1][460]["lambda_att_m"], tables[2][460]["lambda_att_m"]
        baseline = 41.62 - 21.56
        expected = baseline / (baseline / lam1 + math.log(1.35 / 1.27))
        assert lam2 == pytest.approx(expected, rel=1e-6)
        # The live run is untouched and all three runs are listed.
        assert {r["kind"] for r in client.get(f"/api/dives/{dive['id']}/runs").json()} == {
            "live",
            "reanalysis",
        }
        audit = [a["action"] for a in client.get("/api/audit").json()]
        assert audit.count("calibration.add") == 2 and audit.count("reanalysis.start") == 2


def test_cli_builds_versions_from_lab_results_and_the_ingest_records_its_calibration(tmp_path: Path) -> None:
    result = {
        "schema": "camcal.calibration/1",
        "name": "emission_ratio",
        "camera": "A",
        "source": {
            "command": "camcal calibrate emission-ratio /lab/fridge",
            "frame_set": {"path": "/lab/fridge"},
        },
        "values": [{"quantity": "emission_ratio", "value": 1.31, "err": 0.02, "wavelength_nm": 460}],
        "setup": {"emission_ratio": {"460": {"value": 1.31, "err": 0.02}}},
    }
    lin = {
        "schema": "camcal.calibration/1",
        "name": "linearity",
        "source": {"command": "camcal calibrate linearity"},
        "values": [],
        "setup": {"linear_range": [6.0, 236.0]},
    }
    (tmp_path / "er.json").write_text(json.dumps(result))
    (tmp_path / "lin.json").write_text(json.dumps(lin))
    data = tmp_path / "data"
    runner = CliRunner()
    out = runner.invoke(
        cli,
        ["calibration", "add", "--name", "lab", "--result", str(tmp_path / "er.json"), "--data", str(data)],
    )
    assert out.exit_code == 0, out.output
    out = runner.invoke(
        cli,
        ["calibration", "add", "--name", "lab", "--result", str(tmp_path / "lin.json"), "--data", str(data)],
    )
    assert out.exit_code == 0 and "version 2" in out.output
    bad = runner.invoke(
        cli,
        ["calibration", "add", "--name", "lab", "--result", str(tmp_path / "nope.json"), "--data", str(data)],
    )
    assert bad.exit_code == 2
    store = Store.open(data, sqlite_synchronous="NORMAL")
    v2 = store.call(queries.calibration, "lab@2")
    assert v2["values"]["setup"]["emission_ratio"]["460"]["value"] == 1.31  # carried from v1
    assert v2["values"]["setup"]["linear_range"] == [6.0, 236.0]
    assert (
        store.call(queries.calibration, "lab")["version"] == 2
        and store.call(queries.calibration, "lab@1")["version"] == 1
    )
    svc = IngestService(
        IngestConfig(
            data_dir=data,
            bind="tcp://127.0.0.1:*",
            events_bind=None,
            workers=1,
            sqlite_synchronous="NORMAL",
            calibration="lab@2",
            plaintext=True,
        ),
        store=store,
    )
    svc.start()
    try:
        assert svc.config.setup.linear_range == (6.0, 236.0)
        with store.read() as s:
            from storage.models import AnalysisRun, Dive

            assert s.get(Dive, svc.dive.id).calibration_id == v2["id"]
            assert s.get(AnalysisRun, svc.run.id).calibration_id == v2["id"]
    finally:
        svc.stop()
    with pytest.raises(ValueError, match="no calibration"):
        IngestService(
            IngestConfig(
                data_dir=data,
                bind="tcp://127.0.0.1:*",
                events_bind=None,
                calibration="missing",
                plaintext=True,
            )
        ).start()
