"""Several ingest processes on one PostgreSQL database, each serving its own modules."""

from __future__ import annotations

import contextlib
import hashlib
import os
import signal
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import func, select

from camcal.core.frameset import read_manifest
from ingest.service import IngestService
from server.app import create_app
from server.settings import ServerSettings
from storage.models import AnalysisRun, AttenuationPoint, Dive, Frame, FrameResult
from storage.store import Store
from tests.live.conftest import ingest_config
from tests.live.test_faults import free_port
from tests.live.test_ingest import stored_keys, wait_for
from tests.utils.live import make_agent, start_ingest, stop_and_drain


def test_an_ingest_refuses_the_modules_it_does_not_serve(tmp_path: Path) -> None:
    svc = IngestService(ingest_config(tmp_path / "data", modules=("A",)))
    svc.start()
    agents = [make_agent(m, svc.endpoint, tmp_path / f"outbox-{m}")[0] for m in ("A", "B")]
    try:
        for a in agents:
            a.start()
        a, b = agents
        assert wait_for(lambda: a.counters["acked"] >= 4 and svc.refused["B"] >= 2, 20)
        b.runner.stop()  # B is refused: its frames stay in its outbox
        assert stop_and_drain([a], 20)
        assert not b.linked.is_set() and b.counters["acked"] == 0
        assert b.outbox.pending_count() >= b.counters["frames_captured"] > 0, "B must keep its frames"
        assert stored_keys(svc, "B") == [] and len(stored_keys(svc, "A")) == a.counters["frames_captured"]
        health = svc.health()
        assert "B" not in health["modules"] and health["refused"]["B"] >= 2
        assert health["served_modules"] == ["A"]
    finally:
        for x in agents:
            x.stop()
        svc.stop()


@pytest.mark.parametrize("bad", ["A,,B!", ",", "x" * 65])
def test_ingest_refuses_a_bad_module_list(tmp_path: Path, bad: str) -> None:
    from typer.testing import CliRunner

    from camcal.cli import app

    res = CliRunner().invoke(app, ["ingest", "--data", str(tmp_path), "--modules", bad])
    assert res.exit_code == 2 and "--modules: expected module ids" in res.output


def start_ingest_for(
    data: Path, db_url: str, module: str, port: int, events_port: int
) -> subprocess.Popen[bytes]:
    """An ingest serving only ``module`` of the shared dive, on the shared database."""
    extra = ("--db-url", db_url, "--modules", module, "--dive", "trident-shared")
    return start_ingest(data, port, events_port, *extra, log=f"ingest-{module}.log")


@pytest.mark.slow
def test_two_ingests_share_a_database_and_one_survives_sigkill(tmp_path: Path, pg_empty_url: str) -> None:
    """Modules A and B stream to one ingest each; A's ingest is killed mid-stream and restarted.

    Both ingests start together on an empty database (they migrate and create
    the dive and its live run at once). After draining, every frame of both
    modules is stored exactly once, with its bytes, and analysed once.
    """
    data = tmp_path / "data"
    ports = {m: (free_port(), free_port()) for m in ("A", "B")}
    procs = {m: start_ingest_for(data, pg_empty_url, m, *ports[m]) for m in ("A", "B")}
    agents = {
        m: make_agent(
            m,
            f"tcp://127.0.0.1:{ports[m][0]}",
            tmp_path / f"outbox-{m}",
            keys_dir=data / "keys",  # made by start_ingest
            link_timeout_s=2.0,
            ack_timeout_s=4.0,
        )[0]
        for m in ("A", "B")
    }
    store = Store.open(data, pg_empty_url, run_migrations=False)
    # One dashboard server following both ingests, as on a ship with sharded ingests (started
    # once the ingests have migrated the empty database).
    events = ", ".join(f"tcp://127.0.0.1:{ports[m][1]}" for m in ("A", "B"))
    settings = ServerSettings(
        data_dir=data, db_url=pg_empty_url, events=events, run_migrations=False, stale_after_s=3
    )
    dashboard = TestClient(create_app(settings))
    stack = contextlib.ExitStack()

    def health_where(ok: Callable[[dict[str, Any]], bool], what: str) -> dict[str, Any]:
        found: list[dict[str, Any]] = []
        assert wait_for(lambda: ok(h := dashboard.get("/api/health").json()) and not found.append(h), 30), (
            f"dashboard never showed {what}: {dashboard.get('/api/health').json()}"
        )
        return found[0]

    try:
        for a in agents.values():
            a.start()
        assert wait_for(lambda: all(a.counters["acked"] >= 4 for a in agents.values()), 60), _logs(tmp_path)
        stack.enter_context(dashboard)
        both = health_where(
            lambda h: (
                h["status"] == "ok"
                and len(h["ingest"]["ingests"]) == 2
                and all(h["modules"].get(m, {}).get("link") == "up" for m in "AB")
            ),
            "both ingests and both modules up",
        )
        assert both["counters"]["frames_stored"] >= 8
        os.killpg(procs["A"].pid, signal.SIGKILL)
        procs["A"].wait(10)
        acked_b = agents["B"].counters["acked"]
        assert wait_for(lambda: agents["B"].counters["acked"] >= acked_b + 3, 20), (
            "B stalled while A was down"
        )
        one = health_where(lambda h: h["status"] == "degraded", "A's ingest silent")
        assert one["modules"]["B"]["link"] == "up" and one["modules"]["A"]["link"] == "unknown"
        procs["A"] = start_ingest_for(data, pg_empty_url, "A", *ports["A"])
        health_where(lambda h: h["status"] == "ok" and h["modules"]["A"]["link"] == "up", "A's ingest back")
        assert wait_for(lambda: all(a.counters["frames_captured"] >= 16 for a in agents.values()), 60)
        assert stop_and_drain(list(agents.values())), _logs(tmp_path)
        n_frames = _count(store, Frame)
        assert wait_for(lambda: _count(store, FrameResult) == n_frames, 60), "frames left unanalysed"
    finally:
        stack.close()
        for a in agents.values():
            a.stop()
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait(5)
    assert agents["A"].counters["link_lost"] + agents["A"].counters["resends_queued"] >= 1
    with store.read() as s:
        assert [d.name for d in s.scalars(select(Dive))] == ["trident-shared"]
        runs = s.scalars(select(AnalysisRun)).all()
        assert [r.kind for r in runs] == ["live"]
        per_frame = s.execute(select(FrameResult.frame_id, func.count()).group_by(FrameResult.frame_id)).all()
        assert {n for _, n in per_frame} == {1} and len(per_frame) == n_frames
        # near and far camera on different ingests: no live λ_att (docs/scaling.md: shard whole pairs)
        assert s.scalar(select(func.count(AttenuationPoint.id))) == 0
        for m, a in agents.items():
            sent = {(r.boot, r.seq): r for r in read_manifest(a.config.outbox / "frames")}
            rows = list(s.scalars(select(Frame).where(Frame.module_id == m)))
            keys = [(r.boot, r.seq) for r in rows]
            assert len(keys) == len(set(keys)) == len(sent) >= 16, f"module {m}: a frame missing or doubled"
            assert set(keys) == set(sent)
            for r in rows:
                stored = store.files.resolve(r.path).read_bytes()
                original = (a.config.outbox / "frames" / sent[(r.boot, r.seq)].file).read_bytes()
                assert hashlib.sha256(stored).hexdigest() == r.sha256 == hashlib.sha256(original).hexdigest()
    store.close()


def _count(store: Store, model: type) -> int:
    with store.read() as s:
        return int(s.scalar(select(func.count(model.id))))  # type: ignore[attr-defined]


def _logs(tmp_path: Path) -> str:
    return "\n".join(p.read_text(errors="replace")[-3000:] for p in sorted(tmp_path.glob("ingest-*.log")))
