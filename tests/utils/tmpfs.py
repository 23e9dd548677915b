"""A small file system of its own for a test that needs a disk to run full (a tmpfs; needs root)."""

from __future__ import annotations

import errno
import os
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest


@contextmanager
def small_tmpfs(where: Path, size_mb: int) -> Iterator[Path]:
    """Mount a tmpfs of ``size_mb`` at ``where`` (created); skip the test where mounting is not
    allowed (not root). Unmounted afterwards, whatever still uses it."""
    where.mkdir(parents=True, exist_ok=True)
    mount = ["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(where)]
    done = subprocess.run(mount, capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs (needs root): {done.stderr.decode().strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", "-l", str(where)], check=False)


def fill(disk: Path, leave_bytes: int = 0) -> Path:
    """A file taking all of ``disk`` but ``leave_bytes``, however much others write meanwhile.

    Written to the last byte, then cut: a file sized from a free-space reading once failed a clean
    clone's CI with "No space left on device" (frames kept arriving while it was written).
    """
    filler = disk / "filler"
    chunk = bytes(1 << 16)
    with filler.open("wb", buffering=0) as f:
        try:
            while True:
                f.write(chunk)
        except OSError as exc:
            if exc.errno != errno.ENOSPC:
                raise
    os.truncate(filler, max(0, filler.stat().st_size - leave_bytes))
    return filler
