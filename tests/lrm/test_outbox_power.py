"""The SD card through a power cut: the outbox's fsync discipline, traced, and a module killed
mid-write again and again (SIGKILL of the real process: whatever it was writing is cut).

A power cut loses what the kernel had not written; a kill loses what the process had not handed
to the kernel. The first test shows the order that makes a power cut safe (every byte of a frame
durable before its row, the row durable before the ship is offered the frame), the second that
the card reads back whole after any interruption and that the ship ends with exactly the card's
frames.
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import threading
import time
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from camcal.core.frameset import ManifestRow, read_manifest
from camcal.core.framewriter import FrameSetWriter
from camcal.core.images import decode_frame
from camcal.core.schedule import Shot
from lrm.agent import Agent, AgentConfig
from lrm.camera import CapturedFrame
from lrm.outbox import Outbox
from lrm.runner import Capture
from tests.utils.live import RealClock, wait_for


def _path_of(fd: int) -> str:
    return os.readlink(f"/proc/self/fd/{fd}")


def test_a_frame_is_durable_before_its_row_and_its_row_before_the_ship_is_offered_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    trace: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace
    monkeypatch.setattr(os, "fsync", lambda fd: (trace.append(("fsync", _path_of(fd))), real_fsync(fd))[1])
    monkeypatch.setattr(os, "replace", lambda a, b: (trace.append(("rename", str(b))), real_replace(a, b))[1])
    frames = iter(range(2))

    def source(stop: threading.Event) -> Capture | None:
        if next(frames, None) is None:
            return None
        pixels = np.random.default_rng(1).integers(0, 200, (32, 48), dtype=np.uint8)
        frame = CapturedFrame(pixels, datetime.now(UTC), 0.05, 8.0, "A")
        return Capture(frame, Shot(460, 0.05, 8.0, 0), 460, 1)

    cfg = AgentConfig(module="A", connect="tcp://127.0.0.1:9", outbox=tmp_path / "card", plaintext=True)
    agent = Agent(cfg, clock=RealClock(), source=source)

    class Offers:  # the queue the comm thread takes the frames to send from
        def put(self, key: tuple[str, int]) -> None:
            trace.append(("offered", f"{key[0]}/{key[1]}"))

    agent._new = Offers()  # type: ignore[assignment]
    trace.clear()
    agent._capture_loop()  # the capture thread's loop, here: two frames, then the source ends
    agent.outbox.close()
    boot_dir = str(tmp_path / "card" / "frames" / agent.boot)
    manifest = str(tmp_path / "card" / "frames" / "manifest.csv")
    for seq in (1, 2):
        image = f"{boot_dir}/A_460_{seq:07d}.png"
        ops = trace[: trace.index(("offered", f"{agent.boot}/{seq}")) + 1]
        del trace[: len(ops)]
        steps = [
            next(i for i, (op, p) in enumerate(ops) if op == "fsync" and Path(p).name.startswith(".A_460")),
            ops.index(("rename", image)),
            ops.index(("fsync", boot_dir)),
            ops.index(("fsync", manifest)),
            len(ops) - 1,
        ]
        assert steps == sorted(steps), ops  # bytes, name, folder, row, then offered
        # the first frame of a boot made its folder: the folder above is made durable too
        assert (("fsync", str(Path(boot_dir).parent)) in ops) == (seq == 1), ops
        assert sum(op == "fsync" for op, _ in ops) == (4 if seq == 1 else 3), ops


def _frame_set(folder: Path, n: int) -> None:
    rng = np.random.default_rng(7)
    with FrameSetWriter(folder) as w:
        for i in range(n):
            w.add(
                rng.integers(0, 60, (96, 128), dtype=np.uint8),
                ManifestRow(
                    i + 1,
                    f"f{i:04d}.png",
                    "A",
                    460,
                    0.05,
                    8.0,
                    timestamp=f"2026-11-28T10:{i // 60:02d}:{i % 60:02d}Z",
                ),
            )


def _check_card(card: Path) -> list[tuple[str, int]]:
    """What the card holds, after it is opened again as a module opens it: every row's image whole,
    each boot's numbers 1, 2, 3... with none twice."""
    box = Outbox(card, "A")  # (drops a row a kill cut short, as a restarted module does)
    box.close()
    assert not box.damaged, box.damaged
    rows = read_manifest(card / "frames")
    by_boot: dict[str, list[int]] = {}
    for r in rows:
        assert not r.error, r.error
        decode_frame((card / "frames" / r.file).read_bytes(), r.file)  # whole: decodes, IEND there
        by_boot.setdefault(r.boot or "", []).append(r.seq or 0)
    for boot, seqs in by_boot.items():
        assert seqs == list(range(1, len(seqs) + 1)), f"boot {boot}: {seqs[:20]}..."
    return [(r.boot or "", r.seq or 0) for r in rows]


def _replay(frames: Path, card: Path, connect: str, log: Any) -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "camcal", "lrm", "replay", str(frames), "--speed", "0", "--plaintext"]
    cmd += ["--outbox", str(card), "--connect", connect]
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONPATH": "."})


def test_a_module_killed_mid_write_leaves_a_card_that_reads_whole_and_reaches_the_ship_once(
    tmp_path: Path,
) -> None:
    from ingest.service import IngestService
    from storage.models import Frame
    from tests.live.conftest import ingest_config

    frames, card = tmp_path / "recorded", tmp_path / "card"
    _frame_set(frames, 150)
    rnd = random.Random(3)
    with (tmp_path / "module.log").open("wb") as log:
        manifest = card / "frames" / "manifest.csv"
        for _ in range(3):  # no ship yet: every frame waits on the card
            before = manifest.stat().st_size if manifest.exists() else 0
            proc = _replay(frames, card, "tcp://127.0.0.1:9", log)
            assert wait_for(lambda b=before: manifest.exists() and manifest.stat().st_size > b + 500, 60)
            time.sleep(rnd.uniform(0.05, 0.6))  # amid the writes: an image, a row, a log line
            proc.send_signal(signal.SIGKILL)
            proc.wait(10)
            held = _check_card(card)
        assert len({b for b, _ in held}) == 3 and len(held) > 9
        svc = IngestService(ingest_config(tmp_path / "data"))
        svc.start()
        try:
            proc = _replay(frames, card, svc.endpoint, log)
            assert proc.wait(120) == 0, (tmp_path / "module.log").read_text()[-2000:]
        finally:
            svc.stop()
    on_card = _check_card(card)
    with svc.store.read() as s:
        on_ship = sorted((f.boot, f.seq) for f in s.query(Frame).all())
    assert on_ship == sorted(on_card), "the ship lost a frame of the card or has one twice"
