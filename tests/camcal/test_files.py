"""Writes that appear whole or not at all, and leave nothing behind when they fail."""

from __future__ import annotations

from pathlib import Path

import pytest

from camcal.core.files import write_atomic


def test_a_write_appears_whole_under_its_name(tmp_path: Path) -> None:
    target = tmp_path / "frame.png"
    write_atomic(target, b"first")
    write_atomic(target, memoryview(b"second, longer"))
    assert target.read_bytes() == b"second, longer"
    assert [p.name for p in tmp_path.iterdir()] == ["frame.png"]


def test_a_failed_write_leaves_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.mkdir()  # the rename over a folder fails after the data was written and synced
    with pytest.raises(OSError):
        write_atomic(target, b"x" * 100_000)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken"] and not any(target.iterdir())
