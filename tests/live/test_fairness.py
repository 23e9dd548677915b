"""No module can starve another (issue 38, item 1): a real ``camcal ingest`` process, two modules.

Module B sends three sensor batches just under the 32 MiB part limit (70 000 rows of
64 columns, the largest kind of valid message), then module A sends frames, one
after the other's acknowledgement. Before the ingest was a pipeline of stages,
its receiving thread checked B's batches one after the other (seconds each)
before it read A's next frame: A's acknowledgements waited for B's batches. Now
A's frames are checked between the steps of B's and stored in the next turn,
and B, holding more than `module_queue_mb` on the ship, is refused ``busy``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

from camcal.core import wire
from tests.utils.rogue import IngestProbe
from tests.utils.wiremsgs import frame_parts, sensors_parts

COLUMNS = (*wire.SENSOR_COLUMNS, *(f"extra_{i}" for i in range(54)))


def big_batch(seq: int) -> list[bytes]:
    """A valid sensor batch of B just under the ship's 32 MiB part limit."""
    row = b"[1800000000.25," + b",".join([b"0.1234"] * (len(COLUMNS) - 1)) + b"]"
    rows = (32 * 1024 * 1024 - 64) // (len(row) + 1)
    payload = b"[" + b",".join([row] * rows) + b"]"
    assert len(payload) < 32 * 1024 * 1024
    return sensors_parts(payload, COLUMNS, count=rows, module="B", boot="flood", seq=seq)


def hello(module: str, boot: str) -> list[bytes]:
    return [json.dumps({"v": 1, "type": "hello", "module": module, "boot": boot}).encode()]


def test_a_flooding_module_waits_behind_itself_not_in_front_of_another(tmp_path: Path) -> None:
    probe = IngestProbe(tmp_path / "data")
    probe.wait_ready()
    a, b = probe.rogue("A"), probe.rogue("B")
    try:
        assert [m.type for m in a.send(hello("A", "a1"))] == ["welcome"]
        assert [m.type for m in b.send(hello("B", "flood"))] == ["welcome"]
        for seq in (1, 2, 3):
            b.sock.send_multipart(big_batch(seq))
        time.sleep(0.5)  # B's batches are on the ship (or on their way)
        acked_a = []
        for seq in range(1, 6):
            replies = a.send(frame_parts(module="A", camera="A", boot="a1", seq=seq), wait_s=60)
            assert [(m.type, m.ranges[0][1:]) for m in replies] == [("ack", (seq, seq))], replies
            acked_a.append(seq)
        b_answers = b.collect(0.2, expect=10)
        b_acks = [m for m in b_answers if m.type == "ack"]
        assert b_acks == [], "B's batches were stored before A's five frames: A waited behind B"
        busy = [m for m in b_answers if m.type == "nack"]
        assert [(m.reason, m.retry, m.seq) for m in busy] == [("busy", True, 3)], busy
        health = probe.health()
        assert health["modules"]["A"]["link"] == "up"
        assert health["modules"]["B"]["busy_refused"] == 1
        assert probe.alive()
    finally:
        a.close()
        b.close()
        probe.stop()
