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


def test_an_append_the_full_disk_cuts_is_taken_back_and_never_lands_later(tmp_path: Path) -> None:
    """A real full file system (a 1 MB tmpfs; needs root, skipped otherwise): a line that only
    partly fits fails whole, the file is as it was, and the next line after space is freed is the
    next line in the file (before, the failed line's buffered rest landed with it)."""
    from camcal.core.files import AppendLog
    from tests.utils.tmpfs import fill, small_tmpfs

    page = 4096
    with small_tmpfs(tmp_path / "disk", 1) as disk:
        log = AppendLog(disk / "sensors.jsonl", fsync=True)
        written: list[str] = []
        while page - log.path.stat().st_size % page >= 40:  # the last page nearly full
            written.append(f"line {len(written)}: " + "x" * 50 + "\n")
            log.append(lambda fh, text=written[-1]: fh.write(text))
        filler = fill(disk)  # not a byte left beyond that page
        with pytest.raises(OSError):
            log.append(lambda fh: fh.write("the line that does not fit " + "y" * 60 + "\n"))
        assert log.path.read_text() == "".join(written)
        filler.unlink()
        log.append(lambda fh: fh.write("after\n"))
        log.close()
        assert log.path.read_text() == "".join(written) + "after\n"
