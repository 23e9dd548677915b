"""A link lost for good: `camcal import` of the SD card fills the gap; `camcal export` writes the dive."""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from sqlalchemy import func, select
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core.frameset import read_manifest
from ingest.service import IngestService
from storage import queries
from storage.models import Frame, FrameResult, SensorBatch
from storage.store import Store
from tests.live.conftest import ingest_config
from tests.live.test_ingest import wait_for
from tests.utils.live import TcpProxy, camcal_cli, make_agent


def frame_keys(store: Store, module: str) -> dict[tuple[str, int], Frame]:
    with store.read() as s:
        return {(f.boot, f.seq): f for f in s.scalars(select(Frame).where(Frame.module_id == module))}


def sensor_keys(store: Store, module: str) -> set[tuple[str, int]]:
    with store.read() as s:
        rows = s.execute(select(SensorBatch.boot, SensorBatch.seq).where(SensorBatch.module_id == module))
        return {(b, q) for b, q in rows}


def count(store: Store, model) -> int:
    with store.read() as s:
        return int(s.scalar(select(func.count(model.id))))


def test_link_lost_for_good_then_the_sd_card_import_fills_the_gap_and_export_writes_the_dive(
    tmp_path: Path,
) -> None:
    data, outbox = tmp_path / "data", tmp_path / "outbox-A"
    svc = IngestService(ingest_config(data))
    svc.start()
    proxy = TcpProxy(int(svc.endpoint.rsplit(":", 1)[1]))
    # Frequent heartbeats: the ship hears how far the module got well before the stalled
    # link's ZMTP heartbeat timeout (3 s) breaks the connection.
    agent, _ = make_agent("A", proxy.endpoint, outbox, link_timeout_s=2.0, ack_timeout_s=5.0, heartbeat_s=0.3)
    try:
        agent.start()
        assert wait_for(lambda: agent.counters["acked"] >= 6, 30)
        # The fibre fails: first the ship's answers stop coming back, while the module's heartbeats
        # still tell the ship how far it has got; then nothing gets through any more.
        proxy.stall()
        link = svc.links["A"]
        assert wait_for(
            lambda: link.last_seq > max(svc.store.call(queries.known_seqs, "A", agent.boot)) + 2, 10
        )
        proxy.cut()
        assert wait_for(lambda: svc.store.call(queries.open_gaps, "A"), 15), "no gap after the link was lost"
        gap = svc.store.call(queries.open_gaps, "A")[0]
        assert gap.boot == agent.boot
        # The module keeps capturing into its outbox until the dive is over.
        n = agent.counters["frames_captured"]
        assert wait_for(lambda: agent.counters["frames_captured"] >= n + 4, 20)
        agent.stop()

        sd = {(r.boot, r.seq): r for r in read_manifest(outbox / "frames")}
        sensor_lines = [json.loads(x) for x in (outbox / "sensors.jsonl").read_text().splitlines()]
        sd_sensors = {(o["boot"], o["seq"]) for o in sensor_lines}
        live = frame_keys(svc.store, "A")
        missing = set(sd) - set(live)
        assert set(live) < set(sd) and len(missing) >= 4
        assert all(gap.first_seq <= q for _, q in missing)
        assert sensor_keys(svc.store, "A") < sd_sensors

        def mtimes() -> dict[tuple[str, int], int]:
            return {
                k: svc.store.files.resolve(f.path).stat().st_mtime_ns
                for k, f in frame_keys(svc.store, "A").items()
            }

        before = mtimes()
        # Back on deck: the SD card is imported while the ingest still runs.
        res = camcal_cli("import", str(outbox), "--data", str(data), "--workers", "1")
        assert res.returncode == 0, res.stderr
        assert f"{len(missing)} frames imported, {len(live)} already present" in res.stdout
        stored = frame_keys(svc.store, "A")
        assert set(stored) == set(sd), "the import must add exactly the frames the link lost"
        for key, f in stored.items():
            on_sd = (outbox / "frames" / sd[key].file).read_bytes()
            assert hashlib.sha256(on_sd).hexdigest() == f.sha256
            assert svc.store.files.resolve(f.path).read_bytes() == on_sd
            assert (f.source == "import") == (key in missing)
        assert sensor_keys(svc.store, "A") == sd_sensors
        assert svc.store.call(queries.open_gaps, "A") == []
        after = mtimes()
        assert {k: after[k] for k in before} == before, "frames already stored were written again"
        n_frames = count(svc.store, Frame)
        assert wait_for(lambda: count(svc.store, FrameResult) == n_frames, 30), "frames left unanalysed"
        with svc.store.read() as s:
            imported_ok = s.scalar(
                select(func.count(FrameResult.id))
                .join(Frame, Frame.id == FrameResult.frame_id)
                .where(Frame.source == "import", FrameResult.status == "ok")
            )
        assert imported_ok == len(missing)

        # Importing again changes nothing.
        n_sensor_batches = count(svc.store, SensorBatch)
        again = camcal_cli("import", str(outbox), "--data", str(data), "--workers", "1")
        assert again.returncode == 0, again.stderr
        assert f"0 frames imported, {len(sd)} already present, 0 sensor batches, 0 analysed" in again.stdout
        assert count(svc.store, Frame) == n_frames
        assert count(svc.store, FrameResult) == n_frames
        assert count(svc.store, SensorBatch) == n_sensor_batches
        assert mtimes() == after

        # The dive's tables, with every stored frame and its result.
        out = tmp_path / "export"
        exp = camcal_cli("export", "--out", str(out), "--data", str(data))
        assert exp.returncode == 0, exp.stderr
        table = pq.read_table(out / "frames.parquet")
        assert table.num_rows == n_frames
        assert sorted(table.column("sha256").to_pylist()) == sorted(f.sha256 for f in stored.values())
        assert table.column("status").to_pylist() == ["ok"] * n_frames
        assert None not in table.column("i_center_gray").to_pylist()
        with (out / "frames.csv").open(newline="") as fh:
            rows = list(csv.DictReader(fh))
        assert len(rows) == n_frames
        assert {(r["boot"], int(r["seq"])) for r in rows} == set(sd)
        samples = pq.read_table(out / "sensor_samples.parquet")
        assert samples.num_rows == sum(len(o["rows"]) for o in sensor_lines)
    finally:
        agent.stop()
        proxy.close()
        svc.stop()


def test_import_of_a_set_with_bad_files_imports_the_rest_and_names_each_bad_one(
    trex_small_set: Path, tmp_path: Path
) -> None:
    folder = tmp_path / "card"
    shutil.copytree(trex_small_set, folder)
    rows = read_manifest(folder)
    bad = {rows[1].file, rows[4].file, rows[7].file, rows[10].file}
    (folder / rows[1].file).unlink()  # missing
    data = (folder / rows[4].file).read_bytes()
    (folder / rows[4].file).write_bytes(data[: len(data) // 2])  # truncated PNG
    import cv2

    rgba = np.zeros((48, 64, 4), np.uint8)  # colour with alpha (16-bit grayscale is a valid frame now)
    (folder / rows[7].file).write_bytes(cv2.imencode(".png", rgba)[1].tobytes())
    (folder / rows[10].file).write_text("not an image at all\n")
    manifest = folder / "manifest.csv"  # a byte of a row that is not UTF-8 (a failing card)
    line = next(ln for ln in manifest.read_bytes().splitlines() if rows[13].file.encode() in ln)
    manifest.write_bytes(manifest.read_bytes().replace(line, line.replace(b",", b"\xff,", 1)))

    store_dir = tmp_path / "data"
    res = camcal_cli("import", str(folder), "--data", str(store_dir), "--workers", "1")
    assert res.returncode == 0, res.stderr
    good = len(rows) - len(bad) - 1
    assert f"{good} frames imported, 0 already present" in res.stdout
    assert f"{good} analysed" in res.stdout
    assert "5 not imported" in res.stdout
    assert "damaged bytes in this row" in " ".join(res.stdout.split())
    for name in bad:
        assert name in res.stdout, f"{name} not reported"
    assert "file not found" in res.stdout and "4-channel" in res.stdout
    store = Store.open(store_dir, run_migrations=False)
    try:
        with store.read() as s:
            stored = s.scalar(select(func.count(Frame.id)))
            results = s.scalar(select(func.count(FrameResult.id)))
        assert stored == results == good
    finally:
        store.close()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--format", "xlsx"], "unknown export format(s) ['xlsx']; choose from csv, parquet"),
        (["--dive", "nope"], "no dive named 'nope'"),
    ],
)
def test_export_errors_are_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    data = tmp_path / "data"
    store = Store.open(data)
    store.create_dive("d1")
    store.close()
    res = CliRunner().invoke(app, ["export", *args, "--data", str(data), "--out", str(tmp_path / "out")])
    assert res.exit_code == 2
    assert res.stderr.strip().splitlines() == [f"error: {message}"]


def test_import_of_a_card_with_a_damaged_sensor_line_takes_the_others_and_says_which(tmp_path: Path) -> None:
    """A byte of ``sensors.jsonl`` that is not UTF-8 (a failing card): that batch is reported and
    skipped (its values cannot be trusted), the other batches and every frame are imported."""
    from tests.lrm.test_outbox import filled, sensor_rows

    card = tmp_path / "card"
    box = filled(card)  # frames 1, 2, 4 and sensor batch 3 of boot b1
    box.add_sensors("b1", 5, sensor_rows())
    box.close()
    sensors = card / "sensors.jsonl"
    first, second = sensors.read_bytes().splitlines()
    sensors.write_bytes(first.replace(b'"b1"', b'"\xff1"') + b"\n" + second + b"\n")
    res = camcal_cli("import", str(card), "--data", str(tmp_path / "data"), "--workers", "1")
    assert res.returncode == 0, res.stderr
    assert "3 frames imported" in res.stdout and "1 sensor batches" in res.stdout
    assert "damaged bytes in this line" in " ".join(res.stdout.split())


def test_an_export_to_a_full_disk_is_one_line_and_leaves_no_half_written_table(
    dive_data, tmp_path: Path
) -> None:
    """`camcal export` onto a stick with 64 kB left (the dive's tables need more): before, a traceback
    and a table cut where the disk filled; now one line, exit 1, and only whole tables."""
    import pyarrow.parquet as pq

    from tests.utils.tmpfs import small_tmpfs

    with small_tmpfs(tmp_path / "usb", 1) as usb:
        free = shutil.disk_usage(usb).free
        (usb / "filler").write_bytes(b"\0" * (free - 64 * 1024))  # 64 kB left: less than the tables
        res = camcal_cli("export", "--data", str(dive_data[0]), "--out", str(usb / "out"))
        assert res.returncode == 1, res.stdout + res.stderr
        assert "Traceback" not in res.stderr
        assert "cannot write the export into" in " ".join(res.stderr.split()) and "free space" in res.stderr
        left = sorted((usb / "out").iterdir())
        assert not [p for p in left if p.name.startswith(".")], left  # no temporary part
        for p in left:  # each table there is whole
            if p.suffix == ".parquet":
                assert pq.read_table(p).num_rows >= 0
            elif p.suffix == ".json":  # setup.json, run.json
                assert isinstance(json.loads(p.read_text()), dict), p
            else:
                with p.open(newline="") as fh:
                    rows = list(csv.reader(fh))
                assert rows and all(len(r) == len(rows[0]) for r in rows), p


def test_the_dashboards_export_with_no_room_left_is_a_503_that_says_so(dive_data, tmp_path: Path) -> None:
    """The ZIP the dashboard builds in the temporary folder, when that folder's disk is full: a
    503 naming the folder and what to do (was a 500 "internal error"), and no partial file left."""
    import httpx

    from tests.utils.system import camcal_serve
    from tests.utils.tmpfs import small_tmpfs

    with small_tmpfs(tmp_path / "tmp", 1) as tmp:
        (tmp / "filler").write_bytes(b"\0" * (shutil.disk_usage(tmp).free - 16 * 1024))
        with camcal_serve(dive_data[0], env={"TMPDIR": str(tmp)}) as (base, _):
            dive = httpx.get(f"{base}/api/dives").json()[0]["id"]
            r = httpx.get(f"{base}/api/dives/{dive}/export", params={"format": "csv"}, timeout=60)
        assert r.status_code == 503, r.text
        assert f"no room for the export in {tmp}" in r.json()["error"]["message"]
        assert sorted(p.name for p in tmp.iterdir()) == ["filler"]  # the partial ZIP was removed


def test_an_import_onto_a_full_ship_disk_is_one_line_and_the_same_import_again_completes_it(
    trex_small_set: Path, tmp_path: Path
) -> None:
    """The data folder's disk fills during `camcal import`: one line that says what to do (was a
    traceback), and once there is room the same command takes every frame, none twice."""
    import subprocess

    from tests.utils.tmpfs import small_tmpfs

    with small_tmpfs(tmp_path / "ship", 8) as ship:
        data = ship / "data"
        needed = sum(p.stat().st_size for p in trex_small_set.iterdir() if p.suffix == ".png")
        (ship / "filler").write_bytes(b"\0" * (shutil.disk_usage(ship).free - needed // 2))
        res = camcal_cli("import", str(trex_small_set), "--data", str(data), "--workers", "1")
        assert res.returncode == 1, res.stdout + res.stderr
        assert "Traceback" not in res.stderr
        line = " ".join(res.stderr.split())
        assert f"cannot store into {data}" in line and "run the same import again" in line
        (ship / "filler").unlink()  # room again
        subprocess.run(["mount", "-o", "remount,size=64m", str(ship)], check=True)
        again = camcal_cli("import", str(trex_small_set), "--data", str(data), "--workers", "1")
        assert again.returncode == 0, again.stderr
        n = len(read_manifest(trex_small_set))
        store = Store.open(data, run_migrations=False)
        try:
            with store.read() as s:
                frames = s.scalar(select(func.count(Frame.id)))
                keys = s.execute(select(Frame.module_id, Frame.seq)).all()
                results = s.scalar(select(func.count(FrameResult.id)))
        finally:
            store.close()
        assert frames == results == n and len(set(keys)) == n
