"""``camcal reanalyze`` on Dask: frame-set folders (local and in an S3 bucket), stored dives, time spans."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, select
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core.calibrations import record_values
from camcal.core.frameset import parse_setup, read_manifest, read_setup
from ingest.runners import DaskRunner
from storage.models import AnalysisRun, AttenuationPoint, Frame, FrameResult
from storage.store import Store

runner = CliRunner()
BUCKET = "camcal-test"


def reanalyze(*args: str) -> Any:
    return runner.invoke(app, ["reanalyze", *args])


def summary(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())["runs"][0]


def i_center_by_key(data: Path, run_id: int) -> dict[tuple[str, int], float | None]:
    """I_center of a run's frames by (module, seq): the same frame set gives the same keys."""
    store = Store.open(data, run_migrations=False)
    try:
        with store.read() as s:
            rows = s.execute(
                select(Frame.module_id, Frame.seq, FrameResult.i_center_gray)
                .join(FrameResult, FrameResult.frame_id == Frame.id)
                .where(FrameResult.run_id == run_id)
            ).all()
    finally:
        store.close()
    return {(m, int(q)): i for m, q, i in rows}


@pytest.fixture(scope="module")
def s3(trex_small_set: Path) -> Iterator[list[str]]:
    """A moto S3 server on 127.0.0.1 holding the small T-REX set under ``s3://camcal-test/sets/``;
    yields the ``--storage-option`` arguments that reach it."""
    import s3fs
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    options = {
        "key": "testing",
        "secret": "testing",
        "endpoint_url": f"http://{host}:{port}",
        "client_kwargs": {"region_name": "eu-west-1"},
    }
    fs = s3fs.S3FileSystem(**options)
    fs.mkdir(BUCKET)
    fs.put(str(trex_small_set), f"{BUCKET}/sets/trex-small", recursive=True)
    args = []
    for k, v in options.items():
        args += ["--storage-option", f"{k}={json.dumps(v) if isinstance(v, dict) else v}"]
    yield args
    server.stop()


def test_a_folder_and_its_copy_in_a_bucket_give_the_same_results(
    trex_small_set: Path, tmp_path: Path, dask_runner: DaskRunner, s3: list[str]
) -> None:
    scheduler = ["--scheduler", dask_runner.client.scheduler.address]
    local, remote = tmp_path / "local", tmp_path / "remote"
    res = reanalyze(str(trex_small_set), "--data", str(local), *scheduler, "--json", str(tmp_path / "l.json"))
    assert res.exit_code == 0, res.output
    a = summary(tmp_path / "l.json")
    assert a["dive"] == "trex-small" and a["frames"] == 72 and a["ok_frames"] > 60
    truth = json.loads((trex_small_set / "truth.json").read_text())["water"]
    for row in a["attenuation"]:
        expected = truth[str(row["wavelength_nm"])]["lambda_att_m"]
        assert row["lambda_att_m"] == pytest.approx(expected, rel=0.05)
    url = f"s3://{BUCKET}/sets/trex-small"
    res = reanalyze(url, "--data", str(remote), *scheduler, *s3, "--json", str(tmp_path / "r.json"))
    assert res.exit_code == 0, res.output
    b = summary(tmp_path / "r.json")
    assert b["frames"] == 72 and b["attenuation"] == a["attenuation"]
    assert i_center_by_key(remote, b["run_id"]) == i_center_by_key(local, a["run_id"])
    # importing and re-analysing the same folder again adds a run, not frames
    res = reanalyze(url, "--data", str(remote), *scheduler, *s3, "--json", str(tmp_path / "r2.json"))
    assert res.exit_code == 0, res.output
    assert "72 frames" in res.output and summary(tmp_path / "r2.json")["run_id"] != b["run_id"]
    store = Store.open(remote, run_migrations=False)
    with store.read() as s:
        assert len(s.scalars(select(Frame)).all()) == 72
    store.close()


def test_a_stored_dive_and_a_time_span_with_other_distances(
    trex_small_set: Path, tmp_path: Path, dask_runner: DaskRunner
) -> None:
    data, scheduler = tmp_path / "data", ["--scheduler", dask_runner.client.scheduler.address]
    assert reanalyze(str(trex_small_set), "--data", str(data), *scheduler).exit_code == 0
    out = tmp_path / "moved.json"
    dive = ["--dive", "trex-small", "--data", str(data), *scheduler, "--json", str(out)]
    res = reanalyze(*dive, "--distance", "B=45")
    assert res.exit_code == 0, res.output
    moved = summary(out)
    assert moved["calibration"]["cameras"]["B"]["distance_m"] == 45.0
    assert reanalyze(*dive).exit_code == 0
    same = summary(out)
    scale = (45.0 - 21.56) / (41.62 - 21.56)
    for p, q in zip(same["attenuation"], moved["attenuation"], strict=True):
        assert q["lambda_att_m"] == pytest.approx(p["lambda_att_m"] * scale, rel=1e-9)
    # a module clock that was off: its frames are paired at the corrected times (here an hour
    # away from the other camera's, so no visit has both cameras)
    res = reanalyze(*dive, "--clock-offset", "B=3600")
    assert res.exit_code == 0, res.output
    shifted = summary(out)
    assert shifted["calibration"]["cameras"]["B"]["clock_offset_s"] == 3600.0
    store = Store.open(data, run_migrations=False)
    with store.read() as ses:
        points = {
            key: ses.scalar(select(func.count(AttenuationPoint.id)).where(AttenuationPoint.run_id == run))
            for key, run in (("right", same["run_id"]), ("shifted", shifted["run_id"]))
        }
    store.close()
    assert points["right"] > 0 and points["shifted"] == 0  # the station mean pairs by setting: as it was
    assert shifted["attenuation"] == same["attenuation"]
    # a stored calibration record: the run uses its values and records which version it was
    store = Store.open(data, run_migrations=False)
    taped = read_setup(trex_small_set).to_json()
    taped["cameras"]["B"]["distance_m"] = 45.0
    record = store.add_calibration(
        "lab-tape", record_values(parse_setup(taped, "test"), [], ["tape measure"]), actor="test"
    )
    store.close()
    res = reanalyze(*dive, "--calibration", "lab-tape")
    assert res.exit_code == 0, res.output
    by_record = summary(out)
    assert by_record["calibration_record"] == "lab-tape@1"
    assert [a["lambda_att_m"] for a in by_record["attenuation"]] == pytest.approx(
        [a["lambda_att_m"] for a in moved["attenuation"]], rel=1e-9
    )
    store = Store.open(data, run_migrations=False)
    with store.read() as ses:
        run = ses.get(AnalysisRun, by_record["run_id"])
        assert run.calibration_id == record["id"] and run.label.startswith("calibration lab-tape v1")
    store.close()
    res = reanalyze(*dive, "--calibration", "lab-tape@7")
    assert res.exit_code == 2 and "no calibration 'lab-tape@7'" in res.output and "lab-tape@1" in res.output
    # a time span: from the first frame to the last one at 405 nm
    rows = read_manifest(trex_small_set)
    t_end = [r.timestamp for r in rows if r.wavelength_nm == 405][-1]  # rows are in time order
    span = ["--from", rows[0].timestamp, "--to", t_end]
    res = reanalyze(*span, "--data", str(data), *scheduler, "--linear-range", "5,200", "--json", str(out))
    assert res.exit_code == 0, res.output
    s = summary(out)
    assert s["frames"] == sum(1 for r in rows if r.wavelength_nm == 405) == 24
    assert [a["wavelength_nm"] for a in s["attenuation"]] == [405]
    store = Store.open(data, run_migrations=False)
    with store.read() as ses:
        run = ses.get(AnalysisRun, s["run_id"])
        assert run.kind == "reanalysis" and run.calibration["linear_range"] == [5.0, 200.0]
    store.close()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "say what to re-analyse"),
        (["--from", "yesterday"], "--from: 'yesterday' is not an ISO 8601 time"),
        (["--from", "2026-01-02", "--to", "2026-01-01"], "--from must not be later than --to"),
        (["--dive", "nope"], "no camcal store here"),
        (["/nonexistent/set"], "no manifest.csv"),
        (["--dive", "x", "--linear-range", "5"], "--linear-range: give LOW,HIGH"),
        (["--dive", "x", "--storage-option", "novalue"], "--storage-option: expected KEY=VALUE"),
        (["--dive", "x", "--clock-offset", "B"], "--clock-offset: expected KEY=VALUE"),
    ],
)
def test_bad_requests_exit_2_with_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    res = reanalyze(*args, "--data", str(tmp_path / "data"))
    assert res.exit_code == 2, res.output
    assert message in res.output and "Traceback" not in res.output
