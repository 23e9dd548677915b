"""A module killed mid-write again and again (SIGKILL of the real process: whatever it was writing
is cut), then linked to a real ingest: the card reads back whole after every interruption and the
ship ends with exactly the card's frames. (The fsync order that carries this through a power cut,
where the kernel's unwritten pages are lost too: ``tests/lrm/test_outbox_power.py``.)
"""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from camcal.core.frameset import ManifestRow, read_manifest
from camcal.core.framewriter import FrameSetWriter
from camcal.core.images import decode_frame
from ingest.service import IngestService
from lrm.outbox import Outbox
from storage.models import Frame
from tests.live.conftest import ingest_config
from tests.utils.live import wait_for


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


@pytest.mark.slow  # four real module processes (~3 s each to start), killed or run to the end
def test_a_module_killed_mid_write_leaves_a_card_that_reads_whole_and_reaches_the_ship_once(
    tmp_path: Path,
) -> None:
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
