"""Writes that survive a power cut: a file appears whole or not at all, and its rename is durable.

The bottom of the kernel: the frame set, the module's outbox and the ship's
frame store all write through these functions.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from pathlib import Path


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
