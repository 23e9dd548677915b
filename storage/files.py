"""Frame files under the data folder: written atomically, read safely."""

from __future__ import annotations

import os
from pathlib import Path

from camcal.frameset import fsync_dir, write_atomic


class UnsafePath(ValueError):
    """A relative path that would leave the data folder."""


class FrameFiles:
    """Lossless frame files, stored as the bytes the module sent.

    A module sends PNG: storing those bytes unchanged costs no CPU, keeps
    the file bit-identical to the module's SD-card copy (same sha256), and
    takes ~1.8 MB per 5 MP frame. Layout:
    ``frames/<dive>/<module>/<boot>/<seq:08d>.png``.
    """

    def __init__(self, root: Path) -> None:
        self.root = Path(root)

    def relative_path(self, dive_id: int, module: str, boot: str, seq: int, encoding: str = "png") -> str:
        ext = "tif" if encoding == "tiff" else "png"
        return f"frames/{dive_id}/{module}/{boot}/{seq:08d}.{ext}"

    def resolve(self, relative: str) -> Path:
        """The absolute path of a stored file; refuses anything outside the data folder."""
        if not relative or relative.startswith(("/", "\\")) or "\x00" in relative:
            raise UnsafePath(f"not a relative path inside the data folder: {relative!r}")
        path = (self.root / relative).resolve()
        root = self.root.resolve()
        if root != path and root not in path.parents:
            raise UnsafePath(f"path leaves the data folder: {relative!r}")
        return path

    def write(self, relative: str, data: bytes | memoryview, *, fsync: bool = True) -> Path:
        """Write to a temporary name, fsync, rename, fsync the folder."""
        path = self.resolve(relative)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, bytes(data), fsync=fsync)
        if fsync:
            fsync_dir(path.parent)
        return path

    def read(self, relative: str) -> bytes:
        return self.resolve(relative).read_bytes()

    def remove_temporaries(self) -> int:
        """Delete half-written temporary files a killed process left behind."""
        count = 0
        frames = self.root / "frames"
        if not frames.exists():
            return 0
        for dirpath, _dirs, files in os.walk(frames):
            for name in files:
                if name.startswith(".") and ".tmp-" in name:
                    os.unlink(os.path.join(dirpath, name))
                    count += 1
        return count
