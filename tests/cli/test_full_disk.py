"""Any command whose disk fills or turns read-only under it ends with one line and exit 1."""

from __future__ import annotations

import subprocess
from pathlib import Path

from tests.utils.live import camcal_cli
from tests.utils.tmpfs import small_tmpfs


def test_a_command_that_fills_its_disk_says_so_in_one_line(tmp_path: Path) -> None:
    """`camcal simulate-set` (hundreds of MB) into a 2 MB file system: was a traceback."""
    with small_tmpfs(tmp_path / "small", 2) as small:
        res = camcal_cli("simulate-set", str(small / "set"), "--repeats", "1")
        assert res.returncode == 1, res.stderr
        assert "Traceback" not in res.stderr
        assert "failed, no space left: free space or write elsewhere" in " ".join(res.stderr.split())
        subprocess.run(["mount", "-o", "remount,ro", str(small)], check=True)
        res = camcal_cli("simulate-set", str(small / "other"), "--repeats", "1")
        assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
        assert "read-only: remount it read-write or write elsewhere" in " ".join(res.stderr.split())
