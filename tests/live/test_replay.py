"""`camcal lrm replay` streams a recorded frame set into the ingest: every frame once, byte for byte."""

from __future__ import annotations

import csv
import hashlib
import json
import shutil
import subprocess
import sys
from collections import Counter
from datetime import datetime, timedelta
from pathlib import Path

import pytest
from sqlalchemy import func, select

from camcal.core.frameset import read_manifest, read_setup
from ingest.service import IngestService
from storage.models import AttenuationPoint, Frame, FrameResult
from tests.live.conftest import ingest_config
from tests.live.test_ingest import wait_for
from tests.utils.live import cli_env


def replay(folder: Path, camera: str, endpoint: str, outbox: Path, speed: float) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [
            sys.executable,
            "-c",
            "from camcal.cli import main; main()",
            "lrm",
            "replay",
            str(folder),
            "--camera",
            camera,
            "--connect",
            endpoint,
            "--speed",
            str(speed),
            "--outbox",
            str(outbox),
            "--log-level",
            "warning",
            "--plaintext",  # the in-process ingest of these tests (ingest_config) is a plaintext one
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=cli_env(),
    )


def finished(proc: subprocess.Popen[str], timeout: float = 120.0) -> str:
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f"the replay did not finish:\n{out}\n{err}")
    assert proc.returncode == 0, err
    return out


def count(svc: IngestService, model) -> int:
    with svc.store.read() as s:
        return int(s.scalar(select(func.count(model.id))))


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_replays_of_both_cameras_store_every_frame_once_with_its_bytes_and_give_lambda_att(
    trex_small_set: Path, tmp_path: Path
) -> None:
    rows = read_manifest(trex_small_set)
    svc = IngestService(ingest_config(tmp_path / "data", setup=read_setup(trex_small_set)))
    svc.start()
    try:
        procs = {cam: replay(trex_small_set, cam, svc.endpoint, tmp_path / f"ob-{cam}", 0) for cam in "AB"}
        for cam, proc in procs.items():
            n = sum(r.camera == cam for r in rows)
            assert f"sent {n} frames; 0 not acknowledged" in finished(proc)
        n_frames = count(svc, Frame)
        assert n_frames == len(rows)
        assert wait_for(lambda: count(svc, FrameResult) == n_frames, 60), "frames left unanalysed"
        with svc.store.read() as s:
            stored = list(s.scalars(select(Frame)))
            statuses = Counter(s.scalars(select(FrameResult.status)))
            points = list(s.scalars(select(AttenuationPoint)))
        for cam in ("A", "B"):
            recorded = Counter(sha256(trex_small_set / r.file) for r in rows if r.camera == cam)
            assert Counter(f.sha256 for f in stored if f.module_id == cam) == recorded
        for f in stored:
            assert sha256(svc.store.files.resolve(f.path)) == f.sha256
        keys = [(f.module_id, f.boot, f.seq) for f in stored]
        assert len(set(keys)) == len(keys)
        assert statuses["ok"] >= len(rows) // 2
    finally:
        svc.stop()
    truth = json.loads((trex_small_set / "truth.json").read_text())
    by_wl = {p.wavelength_nm: p for p in sorted(points, key=lambda p: p.id)}
    assert set(by_wl) == {405, 460, 525}
    for wl, p in by_wl.items():
        assert p.lambda_att_m == pytest.approx(truth["water"][str(wl)]["lambda_att_m"], rel=0.05), wl


def paced_set(source: Path, out: Path, n: int, interval_s: float) -> float:
    """``n`` frames of camera A from ``source`` with timestamps ``interval_s`` apart; returns the span."""
    rows = [r for r in read_manifest(source) if r.camera == "A"][:n]
    out.mkdir()
    t0 = datetime.fromisoformat(rows[0].timestamp.replace("Z", "+00:00"))
    with (out / "manifest.csv").open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "camera", "wavelength_nm", "exposure_s", "gain_db", "timestamp", "seq"])
        for i, r in enumerate(rows):
            shutil.copy(source / r.file, out / r.file)
            t = (t0 + timedelta(seconds=i * interval_s)).isoformat().replace("+00:00", "Z")
            w.writerow([r.file, "A", r.wavelength_nm, r.exposure_s, r.gain_db, t, i + 1])
    return (n - 1) * interval_s


def test_a_replay_at_recorded_pace_takes_the_recorded_time_over_the_speed(
    trex_small_set: Path, tmp_path: Path, service: IngestService
) -> None:
    speed = 20.0
    span_s = paced_set(trex_small_set, tmp_path / "paced", 8, 6.0)  # 42 s recorded: 2.1 s at 20x
    finished(replay(tmp_path / "paced", "A", service.endpoint, tmp_path / "outbox", speed))
    with service.store.read() as s:
        received = sorted(s.scalars(select(Frame.received_unix_s)))
    assert len(received) == 8
    # A generous lower bound only: the frames are spread over about span / speed, not sent at once.
    assert received[-1] - received[0] >= 0.5 * span_s / speed
