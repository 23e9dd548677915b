"""The store: migrations, idempotent batches, gaps, alarms, safe file paths."""

from __future__ import annotations

from pathlib import Path

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext

from storage import queries
from storage.db import current_revision, head_revision
from storage.files import FrameFiles, UnsafePath
from storage.models import Base
from storage.store import FrameRow, SensorBatchRow, Store


@pytest.fixture
def store(tmp_path: Path, db_url: str | None) -> Store:
    s = Store.open(tmp_path / "data", db_url, sqlite_synchronous="NORMAL")
    yield s
    s.close()


def frame_row(seq: int, module: str = "A", boot: str = "b1") -> FrameRow:
    return FrameRow(
        module_id=module,
        boot=boot,
        seq=seq,
        captured_unix_s=1000.0 + seq,
        received_unix_s=1001.0 + seq,
        wavelength_nm=460,
        exposure_s=0.05,
        gain_db=8.0,
        depth_m=3398.0,
        width_px=64,
        height_px=48,
        path=f"frames/1/{module}/{boot}/{seq:08d}.png",
        size_bytes=10,
        sha256="0" * 64,
    )


def test_migrations_build_exactly_the_models(store: Store) -> None:
    assert current_revision(store.engine) == head_revision()
    with store.engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    assert diff == []
    assert store.integrity_check() == "ok"


def test_resent_frames_and_sensor_batches_are_no_ops(store: Store) -> None:
    dive = store.current_dive()
    samples = [{"t_unix_s": 1.0, "temperature_c": 4.0, "humidity_pct": 30.0}]
    first = store.commit_batch(
        dive.id, [frame_row(1), frame_row(2)], [SensorBatchRow("A", "b1", 3, 1.0, samples)]
    )
    assert set(first.new_frames) == {("A", "b1", 1), ("A", "b1", 2)}
    assert first.new_sensor_batches == [("A", "b1", 3)]
    again = store.commit_batch(
        dive.id, [frame_row(2), frame_row(4)], [SensorBatchRow("A", "b1", 3, 1.0, samples)]
    )
    assert set(again.new_frames) == {("A", "b1", 4)}
    assert again.duplicate_frames == [("A", "b1", 2)]
    assert again.duplicate_sensor_batches == [("A", "b1", 3)]
    assert store.call(queries.known_seqs, "A", "b1") == {1, 2, 3, 4}
    from sqlalchemy import func, select

    from storage.models import SensorSample

    with store.read() as s:
        assert s.scalar(select(func.count(SensorSample.id))) == 1


def test_gap_is_filled_when_every_number_arrives(store: Store) -> None:
    gid = store.record_gap("A", "b1", 5, 7)
    assert [g.id for g in store.call(queries.open_gaps, "A")] == [gid]

    def has(seqs: set[int]):
        return lambda first, last: all(q in seqs for q in range(first, last + 1))

    assert store.fill_gaps("A", "b1", has({5, 6})) == []
    assert store.fill_gaps("A", "b1", has({5, 6, 7})) == [gid]
    assert store.call(queries.open_gaps, "A") == []


def test_alarm_raise_update_clear_and_ack_is_audited(store: Store) -> None:
    alarm, new = store.raise_alarm("tilt:A", "tilt", "MINOR", "tilted 3.5°", "A")
    assert new
    again, changed = store.raise_alarm("tilt:A", "tilt", "MINOR", "tilted 3.5°", "A")
    assert again.id == alarm.id and not changed
    _, changed = store.raise_alarm("tilt:A", "tilt", "MAJOR", "tilted 7°", "A")
    assert changed
    acked = store.ack_alarm(alarm.id, "deck")
    assert acked.acked_by == "deck"
    assert store.clear_alarm("tilt:A").active is False
    assert store.call(queries.active_alarms) == []
    from sqlalchemy import select

    from storage.models import AuditEntry

    with store.read() as s:
        entry = s.scalars(select(AuditEntry)).one()
    assert entry.action == "alarm.ack" and entry.actor == "deck"


@pytest.mark.parametrize("bad", ["../x.png", "/etc/passwd", "frames/../../x", "", "a\x00b"])
def test_file_paths_cannot_leave_the_data_folder(tmp_path: Path, bad: str) -> None:
    with pytest.raises(UnsafePath):
        FrameFiles(tmp_path).resolve(bad)


def test_file_write_is_atomic_and_temporaries_are_cleaned(tmp_path: Path) -> None:
    files = FrameFiles(tmp_path)
    rel = files.relative_path(1, "A", "b1", 3)
    files.write(rel, b"data")
    assert files.read(rel) == b"data"
    stale = files.resolve(rel).with_name(".00000004.png.tmp-123")
    stale.write_bytes(b"half")
    assert files.remove_temporaries() == 1 and not stale.exists()


def test_a_batch_of_files_is_written_whole_each_path_once(tmp_path: Path) -> None:
    files = FrameFiles(tmp_path)
    batch = [
        (files.relative_path(1, m, "b1", seq), f"{m}{seq}".encode() * 1000) for m in "AB" for seq in range(6)
    ]
    resent = (batch[0][0], b"a later copy of the same frame")
    written = files.write_many([*batch, resent])
    assert len(written) == len(batch)
    for rel, data in batch:
        assert files.read(rel) == data  # the first copy of a path is the one kept
    assert not [p for p in tmp_path.rglob("*") if ".tmp-" in p.name]
    with pytest.raises(UnsafePath):  # nothing is written when one path is unsafe
        files.write_many([(files.relative_path(1, "A", "b2", 1), b"x"), ("../escape.png", b"x")])
    assert not files.resolve(files.relative_path(1, "A", "b2", 1)).exists()


def test_batch_checksums_events_and_results_come_back_row_for_row(store: Store) -> None:
    """One lookup answers both tables; events get ids in their order; results of different
    shapes (ok, rejected) go in together and a resent one is skipped."""
    from camcal.core.events import Event, EventKind

    dive = store.current_dive()
    rows = [frame_row(1), frame_row(2)]
    rows[1].sha256 = "2" * 64
    events = lambda f, fid: Event(EventKind.FRAME, {"frame_id": fid, "seq": f.seq}, 1.0, "A", dive.id)  # noqa: E731
    out = store.commit_batch(
        dive.id, rows, [SensorBatchRow("A", "b1", 3, 1.0, [], "3" * 64)], frame_event=events
    )
    assert [e.payload["seq"] for e in out.events] == [1, 2]
    assert out.events[0].id is not None and out.events[1].id == out.events[0].id + 1
    keys = [("A", "b1", q) for q in (1, 2, 3, 9)]
    frames, sensors = store.call(queries.stored_checksums, keys, keys)
    assert frames == {("A", "b1", 1): "0" * 64, ("A", "b1", 2): "2" * 64}
    assert sensors == {("A", "b1", 3): "3" * 64}
    assert store.call(queries.stored_checksums, keys[:1], keys[1:2]) == ({("A", "b1", 1): "0" * 64}, {})

    run = store.analysis_run(dive.id)
    fid1, fid2 = out.new_frames[("A", "b1", 1)], out.new_frames[("A", "b1", 2)]
    ok = {"frame_id": fid1, "status": "ok", "i_center_gray": 5.0, "fit": {"a": 1}, "analysed_unix_s": 2.0}
    bad = {"frame_id": fid2, "status": "rejected", "reason": "saturated", "analysed_unix_s": 2.0}
    assert store.save_results(run.id, [ok, bad]) == 2
    assert store.save_results(run.id, [bad]) == 0
    with pytest.raises(Exception, match="no_such_column"):
        store.save_results(run.id, [{**ok, "frame_id": fid2, "no_such_column": 1}])
    from sqlalchemy import select

    from storage.models import FrameResult

    with store.read() as s:
        got = {r.frame_id: r for r in s.scalars(select(FrameResult).where(FrameResult.run_id == run.id))}
    assert got[fid1].i_center_gray == 5.0 and got[fid1].reason is None
    assert got[fid2].reason == "saturated" and got[fid2].i_center_gray is None and got[fid2].fit is None


def test_visit_upserts_of_one_batch_act_as_if_one_by_one(store: Store) -> None:
    dive = store.current_dive()
    run = store.analysis_run(dive.id)
    base = {"run_id": run.id, "dive_id": dive.id, "wavelength_nm": 470, "t_unix_s": 1.0, "n_pairs": 2}
    a1 = {**base, "visit_key": "a", "lambda_att_m": 20.0, "window_s": 5.0}
    b = {**base, "visit_key": "b", "lambda_att_m": 21.0, "window_s": 5.0}
    a2 = {**base, "visit_key": "a", "lambda_att_m": 22.0, "final": False, "window_s": 5.0}
    c1 = {**a1, "visit_key": "c", "lambda_att_m": 23.0}
    c2 = {**a1, "visit_key": "c", "lambda_att_m": 24.0}  # same columns, same key: one statement
    ids = store.save_visit_points(run.id, [a1, b, c1, a2, c2])
    assert set(ids) == {"a", "b", "c"}
    from sqlalchemy import select

    from storage.models import AttenuationPoint

    def points() -> dict[str, tuple[float, bool]]:
        with store.read() as s:
            q = select(AttenuationPoint).where(AttenuationPoint.run_id == run.id)
            return {p.visit_key: (p.lambda_att_m, p.final) for p in s.scalars(q)}

    assert points() == {"a": (22.0, False), "b": (21.0, True), "c": (24.0, True)}
    assert store.save_visit_points(run.id, [{**b, "lambda_att_m": 30.0}], ["a", "c"]) == {"b": ids["b"]}
    assert points() == {"b": (30.0, True)}
