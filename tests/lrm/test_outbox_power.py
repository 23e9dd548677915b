"""The SD card through a power cut: the outbox's fsync discipline, traced.

A power cut loses what the kernel had not written to the card. What makes it safe is the order:
every byte of a frame durable before its row, the row durable before the ship is offered the
frame. ``tests/live/test_module_killed.py`` kills a real module mid-write and checks what the card
then holds.
"""

from __future__ import annotations

import os
import threading
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from camcal.core.schedule import Shot
from lrm.agent import Agent, AgentConfig
from lrm.camera import CapturedFrame
from lrm.runner import Capture
from tests.utils.live import RealClock


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
