"""An imported frame set brings its own setup.json: everything that reads the dive afterwards uses it.

A set taken 10 m and 25 m from the LEM (not T-REX's 21.56/41.62 m), imported with the real `camcal
import`. The import analysed it with its setup.json, but the dive's readers took the run's
calibration, which an imported dive's live run does not store, and fell back to T-REX's values: the
review page's λ_att table (`/api/dives/{id}/attenuation`), the report and `camcal fit --dive` put
the LEM 21.56/41.62 m away and gave λ_att ~35 % long.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from camcal.divefit import dive_inputs
from camcal.report.collect import collect
from server.app import create_app
from server.settings import ServerSettings
from storage import queries
from storage.store import Store
from tests.utils.live import camcal_cli

DISTANCES_M = {"A": 10.0, "B": 25.0}


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    root = tmp_path_factory.mktemp("own-setup")
    folder, data = root / "near-set", root / "data"
    made = camcal_cli(
        "simulate-set", str(folder), "--width", "640", "--height", "512", "--exposures", "0.02,0.03",
        "--gains", "2,8", "--repeats", "2", "--distance", "A=10", "--distance", "B=25", "--seed", "3",
    )  # fmt: skip
    assert made.returncode == 0, made.stderr
    done = camcal_cli("import", str(folder), "--data", str(data), "--workers", "1")
    assert done.returncode == 0, done.stdout + done.stderr
    truth = json.loads((folder / "truth.json").read_text())
    return {
        "data": data,
        "dive": "near-set",
        "folder": folder,
        "truth": {int(k): v["lambda_att_m"] for k, v in truth["water"].items()},
    }


def test_the_review_pages_table_uses_the_sets_distances(imported: dict[str, object]) -> None:
    data, truth = imported["data"], imported["truth"]
    assert isinstance(data, Path) and isinstance(truth, dict)
    with TestClient(create_app(ServerSettings(data_dir=data, events=None))) as client:
        (dive,) = [d for d in client.get("/api/dives").json() if d["name"] == imported["dive"]]
        table = client.get(f"/api/dives/{dive['id']}/attenuation").json()
    cameras = table["calibration"]["cameras"]
    assert {c: cameras[c]["distance_m"] for c in DISTANCES_M} == DISTANCES_M
    rows = {r["wavelength_nm"]: r for r in table["rows"]}
    assert set(rows) == set(truth)
    for wl, lam in truth.items():
        assert rows[wl]["lambda_att_m"] == pytest.approx(lam, rel=0.03), (wl, rows[wl], lam)


def test_the_runs_say_what_the_live_run_analysed_and_with_what(imported: dict[str, object]) -> None:
    # The live run read "0 frames" for every dive: the count was only kept for re-analyses. And an
    # imported dive's live run stores no calibration of its own: the review page's runs table showed
    # no distances and its re-analysis form ("start from the live run's calibration") came up empty.
    data = imported["data"]
    assert isinstance(data, Path)
    with TestClient(create_app(ServerSettings(data_dir=data, events=None))) as client:
        (dive,) = [d for d in client.get("/api/dives").json() if d["name"] == imported["dive"]]
        (live,) = [r for r in client.get(f"/api/dives/{dive['id']}/runs").json() if r["kind"] == "live"]
    assert dive["n_frames"] == 48
    assert live["n_frames"] == 48
    assert live["calibration"] == {} and live["setup_from"] == "dive"
    assert {c: v["distance_m"] for c, v in live["setup"]["cameras"].items()} == DISTANCES_M


def test_the_report_and_the_dive_fit_use_the_sets_setup(imported: dict[str, object]) -> None:
    data, truth = imported["data"], imported["truth"]
    assert isinstance(data, Path) and isinstance(truth, dict)
    store = Store.open(data, run_migrations=False)
    try:
        report = collect(store, str(imported["dive"]))
        inputs = dive_inputs(store, str(imported["dive"]))
    finally:
        store.close()
    for setup in (report.setup, inputs.setup):
        assert {c: setup.cameras[c].distance_m for c in DISTANCES_M} == DISTANCES_M
    for row in report.attenuation:
        lam = truth[row["wavelength_nm"]]
        assert row["lambda_att_m"] == pytest.approx(lam, rel=0.03), (row, lam)


def test_the_export_says_what_its_numbers_were_computed_with(
    imported: dict[str, object], tmp_path: Path
) -> None:
    out = tmp_path / "export"
    done = camcal_cli("export", "--data", str(imported["data"]), "--out", str(out), "--format", "csv")
    assert done.returncode == 0, done.stderr
    setup = json.loads((out / "setup.json").read_text())
    assert {c: setup["cameras"][c]["distance_m"] for c in DISTANCES_M} == DISTANCES_M
    about = json.loads((out / "run.json").read_text())
    assert about["dive"]["name"] == imported["dive"] and about["run"]["kind"] == "live"
    assert about["setup_from"] == "the dive's own setup (imported)"


def test_a_set_imported_again_with_another_setup_says_the_dive_keeps_its_own(
    imported: dict[str, object], tmp_path: Path
) -> None:
    """A corrected setup.json and the same frames imported again: nothing is imported, and the dive's
    numbers stay those of its calibration. Before, silently so; now the import says which values
    differ and the re-analysis that uses them, which then does."""
    folder, data = imported["folder"], imported["data"]
    assert isinstance(folder, Path) and isinstance(data, Path)
    again = Path(shutil.copytree(folder, tmp_path / "near-set"))
    setup = json.loads((again / "setup.json").read_text())
    setup["cameras"]["A"]["distance_m"] = 10.5
    (again / "setup.json").write_text(json.dumps(setup))
    done = camcal_cli("import", str(again), "--data", str(data), "--dive", str(imported["dive"]))
    said = " ".join((done.stdout + done.stderr).split())
    assert done.returncode == 0, said
    assert "0 frames imported" in said and "keeps the calibration it was analysed with" in said, said
    assert "cameras.A.distance_m 10.0 -> 10.5" in said, said
    words = said.split("To analyse the dive with it: ")[1].split()
    command = words[: words.index("--data") + 2]  # the command, with this store's --data
    assert command[:5] == ["camcal", "reanalyze", "--dive", "near-set", "--setup"], command
    redone = camcal_cli(*command[1:], "--label", "A at 10.5 m")
    assert redone.returncode == 0, redone.stdout + redone.stderr
    store = Store.open(data, run_migrations=False)
    try:
        runs = {
            r["label"]: r for r in store.call(queries.runs, store.call(queries.dive_by_name, "near-set").id)
        }
        assert runs["A at 10.5 m"]["calibration"]["cameras"]["A"]["distance_m"] == 10.5
        live = dive_inputs(store, "near-set")  # the live run keeps the dive's own
        assert live.setup.cameras["A"].distance_m == 10.0
    finally:
        store.close()


def test_the_dive_fit_takes_the_sets_focal_length(imported: dict[str, object], tmp_path: Path) -> None:
    """The set's cameras see 16° over 640 px (focal 2277 px, in its setup.json): `camcal fit` held
    T-REX's 8709 px unless --focal-px said otherwise, and refused the dive ("the LEM's disk measures
    49 px but ... 187 px"). It takes the setup's now."""
    data = imported["data"]
    setup = json.loads((Path(str(imported["folder"])) / "setup.json").read_text())
    done = camcal_cli(
        "fit", "--dive", str(imported["dive"]), "--data", str(data), "--wavelength", "460",
        "--photons", "20000", "--sca-nodes", "40,70", "--templates", "monte-carlo",
        "--cache-dir", str(tmp_path / "templates"),
        "--workers", "2", "--quiet", "--no-systematics", "--no-store", "--json", str(tmp_path / "fit.json"),
        timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    doc = json.loads((tmp_path / "fit.json").read_text())
    assert doc["inputs"]["templates"]["focal_px"] == pytest.approx(setup["focal_px"])
    assert [f["wavelength_nm"] for f in doc["fits"]] == [460]
