"""Writes that survive a power cut and a full disk: a file, or a line appended to one, is there
whole or not at all, and a rename is durable.

The bottom of the kernel: the frame set, the module's outbox and the ship's
frame store all write through these.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TextIO


def write_atomic(path: Path, data: bytes | memoryview, *, fsync: bool = True) -> None:
    """Write ``data`` to a temporary name, fsync, then rename over ``path`` (`write_whole`).

    A reader (or a crash) never sees a half-written file under ``path``.
    """

    def write(tmp: Path) -> None:
        with open(tmp, "wb") as fh:
            fh.write(data)
            if fsync:
                fh.flush()
                os.fsync(fh.fileno())

    write_whole(path, write)


def write_whole(path: Path, write: Callable[[Path], object]) -> None:
    """``write(tmp)`` to a temporary name beside ``path``, then rename it over ``path``: the file is
    there whole or not at all. A write that fails (a full disk) removes its temporary file: what
    did fit must not hold the space others need."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}-{threading.get_native_id()}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def fsync_dir(path: Path) -> None:
    """Make a rename inside ``path`` durable."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


class AppendLog:
    """A text file kept open for appending, each `append` whole or not at all.

    A full disk takes the part of a write that fits and leaves the rest in the handle's buffer,
    where the next write would put it on the disk after all: a line its writer was told had
    failed would land later, whole (a module gives a failed frame's number to its next frame: two
    rows with one number). A failed append closes the handle (dropping what it buffers), cuts
    the file back to its size before the append, reopens it and raises.
    """

    def __init__(self, path: Path, *, fsync: bool, newline: str | None = None) -> None:
        self.path, self.fsync, self._newline = Path(path), fsync, newline
        new = not self.path.exists()
        self.fh: TextIO = self._open()
        if new and fsync:  # the new file's name survives a power cut too, not only its lines
            fsync_dir(self.path.parent)

    def _open(self) -> TextIO:
        return self.path.open("a", newline=self._newline, encoding="utf-8")

    def append(self, write: Callable[[TextIO], object]) -> None:
        """``write(fh)`` then flush (and fsync); the file as it was if any of it fails."""
        held = os.fstat(self.fh.fileno()).st_size  # every append is flushed: nothing is buffered
        try:
            write(self.fh)
            self.fh.flush()
            if self.fsync:
                os.fsync(self.fh.fileno())
        except OSError:
            with contextlib.suppress(OSError):
                self.fh.close()  # closes even when its last flush fails; what it wrote is cut below
            with contextlib.suppress(OSError):
                if self.path.stat().st_size > held:
                    os.truncate(self.path, held)
            self.fh = self._open()
            raise

    def close(self) -> None:
        self.fh.close()
