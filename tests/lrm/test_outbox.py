"""The SD-card outbox: what survives a restart, and the messages rebuilt from it."""

from __future__ import annotations

from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from camcal.core import wire
from camcal.core.frameset import read_manifest
from camcal.core.images import encode_png
from lrm.outbox import Outbox

T0 = datetime(2021, 9, 10, 4, 0, 0, tzinfo=UTC)


def png(seed: int, shape: tuple[int, int] = (48, 64)) -> bytes:
    return encode_png(np.random.default_rng(seed).integers(0, 200, shape, dtype=np.uint8))


def add_frame(box: Outbox, boot: str, seq: int) -> bytes:
    data = png(seq)
    box.add_frame(
        boot,
        seq,
        data,
        captured_at=T0,
        camera="A",
        wavelength_nm=460,
        exposure_s=0.05,
        gain_db=8.0,
        depth_m=3420.0,
        schedule_version=3,
    )
    return data


def sensor_rows(n: int = 3) -> list[list[float | None]]:
    return [[1631246400.0 + i / 10, 4.0, 30.0, 0.1, 0.0, 9.81, 0.05, 0.0, 0.02, None] for i in range(n)]


def filled(root: Path) -> Outbox:
    """An outbox holding frames 1, 2, 4 and sensor batch 3 of boot b1, with 1..2 acknowledged."""
    box = Outbox(root, "A", fsync=False)
    add_frame(box, "b1", 1)
    add_frame(box, "b1", 2)
    box.add_sensors("b1", 3, sensor_rows())
    add_frame(box, "b1", 4)
    box.ack("b1", 1, 2)
    return box


def keys(box: Outbox) -> list[tuple[str, str, int]]:
    return [(e.kind, e.boot, e.seq) for e in box.pending()]


def test_pending_entries_and_acknowledged_ranges_survive_a_restart(tmp_path: Path) -> None:
    box = filled(tmp_path)
    assert keys(box) == [("sensors", "b1", 3), ("frame", "b1", 4)]
    box.close()

    again = Outbox(tmp_path, "A", fsync=False)
    assert keys(again) == [("sensors", "b1", 3), ("frame", "b1", 4)]
    assert again.last_seq("b1") == 4
    assert again.get("b1", 1) is None  # acknowledged before the restart
    assert again.ack("b1", 3, 4) == 2
    again.close()

    third = Outbox(tmp_path, "A", fsync=False)
    assert third.pending_count() == 0
    # Nothing is deleted: the SD card keeps every frame for the import after the dive.
    assert [r.seq for r in read_manifest(tmp_path / "frames")] == [1, 2, 4]
    third.close()


def test_a_new_boot_continues_after_the_old_boots_pending_entries(tmp_path: Path) -> None:
    filled(tmp_path).close()
    box = Outbox(tmp_path, "A", fsync=False)
    assert box.last_seq("b2") == 0
    add_frame(box, "b2", 1)
    assert keys(box) == [("sensors", "b1", 3), ("frame", "b1", 4), ("frame", "b2", 1)]
    box.close()


@pytest.mark.parametrize("cut", ['{"boot":"b1","seq":5,"colu', '{"boot":"b1"'])
def test_a_sensor_line_cut_by_a_power_loss_is_skipped_and_later_lines_survive(
    tmp_path: Path, cut: str
) -> None:
    filled(tmp_path).close()
    with (tmp_path / "sensors.jsonl").open("a", encoding="utf-8") as fh:
        fh.write(cut)  # the power went while this line was being written: no newline

    box = Outbox(tmp_path, "A", fsync=False)
    assert keys(box) == [("sensors", "b1", 3), ("frame", "b1", 4)]
    # The next boot appends after the cut line, not onto it.
    box.add_sensors("b2", 1, sensor_rows(2))
    box.close()

    again = Outbox(tmp_path, "A", fsync=False)
    assert keys(again) == [("sensors", "b1", 3), ("frame", "b1", 4), ("sensors", "b2", 1)]
    again.close()


def test_manifest_and_ack_lines_cut_by_a_power_loss_are_skipped(tmp_path: Path) -> None:
    filled(tmp_path).close()
    with (tmp_path / "frames" / "manifest.csv").open("a", encoding="utf-8") as fh:
        fh.write("b1/A_460_0000005.png,A,46")
    with (tmp_path / "acked.log").open("a", encoding="utf-8") as fh:
        fh.write("b1 3")

    box = Outbox(tmp_path, "A", fsync=False)
    assert keys(box) == [("sensors", "b1", 3), ("frame", "b1", 4)]
    add_frame(box, "b2", 1)
    box.ack("b1", 4, 4)
    box.close()

    again = Outbox(tmp_path, "A", fsync=False)
    assert keys(again) == [("sensors", "b1", 3), ("frame", "b2", 1)]
    again.close()


def test_message_rebuilds_valid_wire_messages_from_the_sd_card(tmp_path: Path) -> None:
    box = filled(tmp_path)
    box.close()
    box = Outbox(tmp_path, "A", fsync=False)
    sent = png(4)
    frame_entry = box.get("b1", 4)
    header, payload = box.message(frame_entry, "A")
    msg, data = wire.decode([bytes(f) for f in wire.encode(header, payload)], allowed=wire.MODULE_TYPES)
    assert isinstance(msg, wire.FrameMsg)
    assert bytes(data) == sent
    assert (msg.module, msg.boot, msg.seq, msg.camera) == ("A", "b1", 4, "A")
    assert (msg.wavelength_nm, msg.exposure_s, msg.gain_db, msg.depth_m) == (460, 0.05, 8.0, 3420.0)
    assert (msg.width_px, msg.height_px, msg.schedule_version) == (64, 48, 3)
    assert msg.captured_at == T0 and msg.sha256 == wire.sha256_hex(sent)

    header, payload = box.message(box.get("b1", 3), "A")
    msg, data = wire.decode([bytes(f) for f in wire.encode(header, payload)], allowed=wire.MODULE_TYPES)
    assert isinstance(msg, wire.SensorsMsg) and (msg.boot, msg.seq, msg.count) == ("b1", 3, 3)
    rows = data  # decode checks a sensor payload and returns its rows
    assert rows[0]["acc_z_m_s2"] == 9.81 and rows[0]["depth_m"] is None
    box.close()


def test_state_files_round_trip_and_unreadable_ones_read_as_missing(tmp_path: Path) -> None:
    box = Outbox(tmp_path, "A", fsync=False)
    assert box.load_json("schedule.json") is None
    box.save_json("schedule.json", {"schedule": {"version": 2}, "state": "paused"})
    assert box.load_json("schedule.json") == {"schedule": {"version": 2}, "state": "paused"}
    (tmp_path / "schedule.json").write_text('{"sched')
    assert box.load_json("schedule.json") is None
    box.append_jsonl("commands.jsonl", {"command_id": "c1", "state": "accepted"})
    with (tmp_path / "commands.jsonl").open("a") as fh:
        fh.write('{"command_id": "c2", "sta')
    assert box.read_jsonl("commands.jsonl") == [{"command_id": "c1", "state": "accepted"}]
    box.close()

    again = Outbox(tmp_path, "A", fsync=False)  # after the reboot, new records follow the cut line
    again.append_jsonl("commands.jsonl", {"command_id": "c3", "state": "done"})
    assert [c["command_id"] for c in again.read_jsonl("commands.jsonl")] == ["c1", "c3"]
    again.close()


def damage(data: bytes, where: bytes, into: bytes) -> bytes:
    """``data`` with the first ``where`` replaced by ``into`` (a failing card's bit flips)."""
    assert where in data
    return data.replace(where, into, 1)


@pytest.mark.parametrize(
    ("what", "file", "change", "still_pending"),
    [  # filled(): frames 1, 2, 4 and sensor batch 3 of b1; 1..2 acknowledged
        ("a number that is not one", "acked.log", lambda d: d + b"b1 3 x\n", [3, 4]),
        ("bytes that are not UTF-8", "acked.log", lambda d: damage(d, b"b1", b"\xff\xfe"), [1, 2, 3, 4]),
        (
            "a range of billions",
            "acked.log",
            lambda d: damage(d, b"b1 1 2", b"b1 1 9000000000"),
            [1, 2, 3, 4],
        ),
        ("JSON that is not a batch", "sensors.jsonl", lambda d: b"[1, 2]\n" + d, [3, 4]),
        ("bytes that are not UTF-8", "sensors.jsonl", lambda d: damage(d, b'"b1"', b'"\xff1"'), [4]),
        ("bytes that are not UTF-8", f"frames/{'manifest.csv'}", lambda d: damage(d, b"b1", b"\xb1"), [3, 4]),
        ("bytes that are not UTF-8", "refused.jsonl", lambda d: b"\xff\n" + d, [3, 4]),
    ],
)
def test_a_damaged_line_on_the_card_is_skipped_and_the_module_still_starts(
    tmp_path: Path, what: str, file: str, change: Any, still_pending: list[int], caplog: Any
) -> None:
    """A failing SD card's damaged line (not a power cut's last line) made the outbox, and with it
    the module, fail to start: now that line is skipped and said, and everything else loads. An
    unreadable acknowledgement costs a resend (the ship stores once), never a message."""
    filled(tmp_path).close()
    (tmp_path / "refused.jsonl").touch()
    path = tmp_path / file
    path.write_bytes(change(path.read_bytes()))
    box = Outbox(tmp_path, "A", fsync=False)
    assert [q for _, _, q in keys(box)] == still_pending, what
    assert box.damaged == {file: 1}, what
    assert "damaged line(s) on the SD card" in caplog.text and file in caplog.text
    add_frame(box, "b1", 5)  # and the card takes more
    assert [q for _, _, q in keys(box)] == [*still_pending, 5]
    box.close()


def test_an_outbox_that_cannot_be_written_says_what_to_do(tmp_path: Path) -> None:
    """Where the card's folder cannot be made (here a file is in its way; a read-only card is the
    CLI test's), the error names the outbox and what to do, and leaves nothing open."""
    from lrm.outbox import OutboxUnavailable

    in_the_way = tmp_path / "card"
    in_the_way.write_text("not a folder\n")
    with pytest.raises(OutboxUnavailable, match="cannot be written") as caught:
        Outbox(in_the_way / "outbox", "A", fsync=False)
    assert str(in_the_way / "outbox") in str(caught.value) and "swap it" in str(caught.value)
