"""A module whose SD card cannot be written does not start with a traceback: one line, exit 3."""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.utils.live import camcal_cli
from tests.utils.tmpfs import small_tmpfs


def test_a_read_only_card_is_one_line_and_exit_3(trex_small_set: Path, tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "card", 4) as card:
        subprocess.run(
            ["mount", "-o", "remount,ro", str(card)], check=True
        )  # a card the kernel set read-only
        res = camcal_cli(
            "lrm", "replay", str(trex_small_set), "--camera", "A", "--outbox", str(card / "outbox"),
            "--connect", "tcp://127.0.0.1:9", "--plaintext",
        )  # fmt: skip
    assert res.returncode == 3, res.stderr
    assert "Traceback" not in res.stderr
    error = " ".join(res.stderr.split())
    assert f"the outbox {card / 'outbox'} cannot be written (Read-only file system)" in error
    assert "remount it read-write" in error
