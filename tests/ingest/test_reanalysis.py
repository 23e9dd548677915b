"""Re-analysis of a dive the live path stored, on a two-worker Dask cluster: beside the live run."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import select

from camcal.core.frameset import Setup, read_setup
from ingest.reanalysis import ReanalysisOptions, reanalyse, start_run
from ingest.runners import DaskRunner
from storage.models import AnalysisRun, AttenuationPoint, FrameResult, LinearityCheck
from storage.store import Store
from tests.utils.pg import SKIP_REASON, fresh_database
from tests.utils.replay import stream_frame_set


@pytest.fixture(scope="module", params=["sqlite", "postgresql"])
def replayed(
    request: pytest.FixtureRequest,
    tmp_path_factory: pytest.TempPathFactory,
    trex_small_set: Path,
    pg_template: tuple[str, str] | None,
) -> Iterator[dict[str, Any]]:
    """The small T-REX set streamed through a real ingest (SQLite or PostgreSQL): a dive with a live run."""
    data = tmp_path_factory.mktemp("replayed") / "data"
    if request.param == "postgresql":
        if pg_template is None:
            pytest.skip(SKIP_REASON)
        with fresh_database(*pg_template) as url:
            yield from _replay(data, url, trex_small_set)
    else:
        yield from _replay(data, None, trex_small_set)


def _replay(data: Path, url: str | None, folder: Path) -> Iterator[dict[str, Any]]:
    info = stream_frame_set(folder, data, db_url=url)
    store = Store.open(data, url, sqlite_synchronous="NORMAL")
    yield {**info, "store": store, "setup": read_setup(folder)}
    store.close()


def results(store: Store, run_id: int) -> dict[int, FrameResult]:
    with store.read() as s:
        return {r.frame_id: r for r in s.scalars(select(FrameResult).where(FrameResult.run_id == run_id))}


def points(store: Store, run_id: int) -> list[AttenuationPoint]:
    with store.read() as s:
        return list(
            s.scalars(
                select(AttenuationPoint)
                .where(AttenuationPoint.run_id == run_id)
                .order_by(AttenuationPoint.wavelength_nm, AttenuationPoint.t_unix_s)
            )
        )


def snapshot(store: Store, run_id: int) -> tuple[Any, ...]:
    """Everything of a run that a re-analysis must never change."""
    res = sorted((f, r.status, r.i_center_gray, r.analysed_unix_s) for f, r in results(store, run_id).items())
    pts = [(p.id, p.wavelength_nm, p.lambda_att_m) for p in points(store, run_id)]
    with store.read() as s:
        lin = sorted(
            (c.module_id, c.wavelength_nm, c.sweep, c.slope)
            for c in s.scalars(select(LinearityCheck).where(LinearityCheck.run_id == run_id))
        )
        run = s.get(AnalysisRun, run_id)
        return res, pts, lin, run.calibration, run.status


def with_distance(setup: Setup, camera: str, distance_m: float) -> Setup:
    data = setup.model_dump()
    data["cameras"][camera]["distance_m"] = distance_m
    return Setup.model_validate(data)


def test_dask_reanalysis_reproduces_the_live_i_center(
    replayed: dict[str, Any], dask_runner: DaskRunner
) -> None:
    store, dive_id, live_id = replayed["store"], replayed["dive_id"], replayed["run_id"]
    before = snapshot(store, live_id)
    run_id = start_run(store, dive_id, replayed["setup"], "dask, analysed again")
    opts = ReanalysisOptions(reuse_live=False, batch_size=8)
    n = reanalyse(store, dive_id, run_id, replayed["setup"], opts, runner=dask_runner)
    assert n == replayed["frames"] == 72
    live, again = results(store, live_id), results(store, run_id)
    assert set(again) == set(live)
    for fid, r in live.items():
        assert (again[fid].status, again[fid].reason) == (r.status, r.reason)
        assert again[fid].i_center_gray == r.i_center_gray and again[fid].background_gray == r.background_gray
    assert again[next(iter(again))].analysed_unix_s > before[0][0][3]
    assert points(store, run_id), "no λ_att series"
    with store.read() as s:
        assert s.get(AnalysisRun, run_id).status == "done" and s.get(AnalysisRun, run_id).n_frames == 72
    assert snapshot(store, live_id) == before


def test_changed_distances_change_lambda_att_and_the_live_run_stays(
    replayed: dict[str, Any], dask_runner: DaskRunner
) -> None:
    """λ_att = (L_far - L_near) / ln(...): moving camera B scales every λ_att by the distance ratio."""
    store, dive_id, live_id = replayed["store"], replayed["dive_id"], replayed["run_id"]
    setup = replayed["setup"]
    before = snapshot(store, live_id)
    opts = ReanalysisOptions()
    same = start_run(store, dive_id, setup, "same calibration")
    moved = start_run(store, dive_id, with_distance(setup, "B", 45.0), "B at 45 m")
    assert reanalyse(store, dive_id, same, setup, opts, runner=dask_runner) == 72  # copied from live
    reanalyse(store, dive_id, moved, with_distance(setup, "B", 45.0), opts, runner=dask_runner)
    a, b = points(store, same), points(store, moved)
    assert len(a) == len(b) > 0
    scale = (45.0 - 21.56) / (41.62 - 21.56)
    for p, q in zip(a, b, strict=True):
        assert (p.wavelength_nm, p.t_unix_s) == (q.wavelength_nm, q.t_unix_s)
        assert q.lambda_att_m == pytest.approx(p.lambda_att_m * scale, rel=1e-9)
    assert {r.i_center_gray for r in results(store, moved).values()} == {
        r.i_center_gray for r in results(store, live_id).values()
    }
    assert snapshot(store, live_id) == before


def test_a_changed_linear_range_analyses_again_and_rejects_more(
    replayed: dict[str, Any], dask_runner: DaskRunner
) -> None:
    store, dive_id, live_id = replayed["store"], replayed["dive_id"], replayed["run_id"]
    data = replayed["setup"].model_dump()
    data["linear_range"] = (5.0, 120.0)
    narrow = Setup.model_validate(data)
    run_id = start_run(store, dive_id, narrow, "narrow linear range")
    reanalyse(store, dive_id, run_id, narrow, ReanalysisOptions(batch_size=5), runner=dask_runner)
    live, again = results(store, live_id), results(store, run_id)
    n_ok = sum(r.status == "ok" for r in live.values())
    assert 0 < sum(r.status == "ok" for r in again.values()) < n_ok
    assert {r.reason for r in again.values() if r.status != "ok"} >= {"saturated"}


def test_the_api_still_starts_a_reanalysis(replayed: dict[str, Any]) -> None:
    from fastapi.testclient import TestClient

    from server.app import create_app
    from server.settings import ServerSettings

    store, dive_id = replayed["store"], replayed["dive_id"]
    app = create_app(
        ServerSettings(data_dir=store.files.root, events=None, operator_tokens={"ops": "token-123456"}),
        store=store,
    )
    with TestClient(app) as client:
        r = client.post(
            f"/api/dives/{dive_id}/reanalyses",
            json={
                "label": "api",
                "cameras": {"B": {"distance_m": 45.0, "distance_err_m": 0.04, "clock_offset_s": 0.5}},
            },
            headers={"Authorization": "Bearer token-123456"},
        )
        assert r.status_code == 202, r.text
        run_id = r.json()["id"]
        cameras = r.json()["calibration"]["cameras"]
        assert cameras["B"]["clock_offset_s"] == 0.5 and cameras["B"]["distance_m"] == 45.0
        end = time.monotonic() + 60
        while time.monotonic() < end:
            run = next(x for x in client.get(f"/api/dives/{dive_id}/runs").json() if x["id"] == run_id)
            if run["status"] not in ("queued", "running"):
                break
            time.sleep(0.1)
    assert run["status"] == "done" and run["n_frames"] == 72
    assert points(store, run_id)


def analyse_or_die(tasks: list[Any], config: Any, storage_options: Any = None) -> list[Any]:
    """In a worker process: the real analysis, but a batch with the poisoned frame kills the process
    (as a decoder crash or the OOM killer would; the one stand-in, a real crash cannot be had on demand)."""
    import os

    from ingest.worker import analyse_batch

    if any(str(t[1]).endswith("poison.png") for t in tasks):
        os._exit(3)
    return analyse_batch(tasks, config, storage_options)


def test_a_frame_that_kills_its_analysis_process_costs_the_run_only_that_frame(
    replayed: dict[str, Any],
) -> None:
    """On a local pool a dead process breaks every batch still running; the frames not done are
    analysed one at a time, and only the one that kills a process on its own is rejected."""
    from analysis import FrameConfig
    from ingest.reanalysis import analyse_into_run
    from ingest.runners import LocalRunner
    from storage import queries

    store, dive_id, live_id = replayed["store"], replayed["dive_id"], replayed["run_id"]
    run_id = start_run(store, dive_id, replayed["setup"], "a poisoned frame")
    tasks = [(fid, str(store.files.resolve(path))) for fid, path in store.call(queries.dive_frames, dive_id)]
    poison = tasks[len(tasks) // 3][0]
    tasks = [(fid, "/nowhere/poison.png" if fid == poison else url) for fid, url in tasks]
    n = analyse_into_run(
        store,
        run_id,
        tasks,
        FrameConfig(**replayed["setup"].frame_settings(None)),
        ReanalysisOptions(batch_size=4),
        LocalRunner(2),
        analyse=analyse_or_die,
    )
    live, again = results(store, live_id), results(store, run_id)
    assert n == len(tasks) and set(again) == {fid for fid, _ in tasks}  # every frame has its result
    assert again[poison].status == "rejected" and again[poison].reason == "analysis_crashed"
    others = [fid for fid, _ in tasks if fid != poison]
    assert [again[f].i_center_gray for f in others] == [live[f].i_center_gray for f in others]
