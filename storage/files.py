"""Frame files under the data folder (written atomically, read safely), and reading through fsspec.

The store's frames live in the data folder; a copy of them (or any frame
set) may live in object storage. `read_url` and `RemoteFolder` read a local
path and an ``s3://`` (or any fsspec) URL the same way, so re-analysis
workers need no shared file system.
"""

from __future__ import annotations

import errno
import os
import stat
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from camcal.core.files import fsync_dir, write_atomic
from camcal.core.wire.models import is_id


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
        self._root: Path | None = None
        self._pool: ThreadPoolExecutor | None = None

    def relative_path(self, dive_id: int, module: str, boot: str, seq: int, encoding: str = "png") -> str:
        """Where a frame is stored; `UnsafePath` for a module or boot that is not an id (``..``)."""
        if not is_id(module) or not is_id(boot):
            raise UnsafePath(f"module {module!r} and boot {boot!r} must be ids (not only dots)")
        ext = "tif" if encoding == "tiff" else "png"
        return f"frames/{dive_id}/{module}/{boot}/{seq:08d}.{ext}"

    def resolve(self, relative: str) -> Path:
        """The absolute path of a stored file; refuses anything outside the data folder."""
        if not relative or relative.startswith(("/", "\\")) or "\x00" in relative:
            raise UnsafePath(f"not a relative path inside the data folder: {relative!r}")
        path = (self.root / relative).resolve()
        root = self._resolved_root()
        if root != path and root not in path.parents:
            raise UnsafePath(f"path leaves the data folder: {relative!r}")
        return path

    def _resolved_root(self) -> Path:
        """The data folder's real path, found once (a realpath walks every component)."""
        if self._root is None:
            self._root = self.root.resolve()
        return self._root

    def read_regular(self, relative: str, under: str) -> bytes:
        """The bytes of a stored file in folder ``under`` (``frames``, ``thumbs``), for serving.

        Every component of the path is opened with ``O_NOFOLLOW`` relative to
        the folder before it: a symbolic link anywhere on the way (a frame
        file, a module's folder, ``thumbs`` itself) is refused, as is anything
        but a regular file, and no path can leave ``under``. Raises
        `FileNotFoundError` for a missing file and `UnsafePath` otherwise.
        """
        parts = relative.split("/")
        if parts[0] != under or len(parts) < 2 or any(not p or p in (".", "..") for p in parts):
            raise UnsafePath(f"not a path inside {under}/: {relative!r}")
        flags = os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC
        fd = os.open(self.root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        try:
            for name in parts[:-1]:
                try:
                    nxt = os.open(name, flags | os.O_DIRECTORY, dir_fd=fd)
                except OSError as exc:
                    if exc.errno in (errno.ELOOP, errno.ENOTDIR):
                        raise UnsafePath(f"{relative}: {name} is not a folder (a symbolic link?)") from None
                    raise
                os.close(fd)
                fd = nxt
            try:
                file_fd = os.open(parts[-1], flags | os.O_NONBLOCK, dir_fd=fd)  # a FIFO must not block
            except OSError as exc:
                if exc.errno == errno.ELOOP:
                    raise UnsafePath(f"{relative} is a symbolic link") from None
                raise
        finally:
            os.close(fd)
        with os.fdopen(file_fd, "rb") as fh:
            if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
                raise UnsafePath(f"{relative} is not a regular file")
            return fh.read()

    def write(self, relative: str, data: bytes | memoryview, *, fsync: bool = True) -> Path:
        """Write to a temporary name, fsync, rename, fsync the folder."""
        return self.write_many([(relative, data)], fsync=fsync)[0]

    def write_many(
        self, items: Sequence[tuple[str, bytes | memoryview]], *, fsync: bool = True
    ) -> list[Path]:
        """Write files as `write` does, their fsyncs overlapping on a few threads; each folder
        is fsynced once, after every rename in it. When this returns, all are durable.
        A path given twice is written once, with its first data."""
        unique: dict[str, bytes | memoryview] = {}
        for relative, data in items:
            unique.setdefault(relative, data)
        paths = [self.resolve(relative) for relative in unique]
        folders = sorted({p.parent for p in paths})
        for folder in folders:
            folder.mkdir(parents=True, exist_ok=True)

        def one(job: tuple[Path, bytes | memoryview]) -> None:
            write_atomic(*job, fsync=fsync)

        jobs = list(zip(paths, unique.values(), strict=True))
        if fsync and len(jobs) > 1:
            list(self._writers().map(one, jobs))  # re-raises the first error
        else:
            for job in jobs:
                one(job)
        if fsync:
            for folder in folders:
                fsync_dir(folder)
        return paths

    def _writers(self) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=4, thread_name_prefix="frame-write")
        return self._pool

    def read(self, relative: str) -> bytes:
        return self.resolve(relative).read_bytes()

    def url(self, relative: str, base_url: str | None = None) -> str:
        """Where a stored file is for fsspec: under ``base_url`` (a mirror of the data folder in
        object storage, e.g. ``s3://bucket/camcal-data``) if given, else its local path."""
        path = self.resolve(relative)  # refuses unsafe paths either way
        if base_url is None:
            return str(path)
        return f"{base_url.rstrip('/')}/{path.relative_to(self.root.resolve()).as_posix()}"

    def remove_temporaries(self, modules: Sequence[str] = ()) -> int:
        """Delete half-written temporary files a killed process left behind.

        With ``modules``, only under those modules' folders: ingest processes
        that share a data folder each clean up after themselves, never under
        a module another process is writing.
        """
        count = 0
        frames = self.root / "frames"
        if not frames.exists():
            return 0
        tops = [d / m for d in frames.iterdir() if d.is_dir() for m in modules] if modules else [frames]
        for top in tops:
            for dirpath, _dirs, files in os.walk(top):
                for name in files:
                    if name.startswith(".") and ".tmp-" in name:
                        os.unlink(os.path.join(dirpath, name))
                        count += 1
        return count


def read_url(url: str, storage_options: dict[str, Any] | None = None) -> bytes:
    """The bytes at a local path or an fsspec URL (``s3://bucket/key``, ``file://``, ``memory://``)."""
    import fsspec

    with fsspec.open(url, "rb", **(storage_options or {})) as fh:
        return fh.read()  # type: ignore[no-any-return]


class RemoteFolder:
    """A folder read through fsspec: a local path or a URL prefix such as ``s3://bucket/sets/dive-7``."""

    def __init__(self, url: str | Path, storage_options: dict[str, Any] | None = None) -> None:
        import fsspec

        self.url = str(url).rstrip("/") or "/"
        self.storage_options = dict(storage_options or {})
        self.fs, self.root = fsspec.core.url_to_fs(self.url, **self.storage_options)

    def _path(self, name: str) -> str:
        if name.startswith(("/", "\\")) or ".." in Path(name).parts:
            raise UnsafePath(f"not a relative path inside {self.url}: {name!r}")
        return f"{self.root.rstrip('/')}/{name}"

    def child(self, name: str) -> RemoteFolder:
        return RemoteFolder(f"{self.url}/{name}", self.storage_options)

    def exists(self, name: str) -> bool:
        return bool(self.fs.exists(self._path(name)))

    def read_bytes(self, name: str) -> bytes:
        """The bytes of ``name`` in the folder; `FileNotFoundError` if there is no such file."""
        return bytes(self.fs.cat_file(self._path(name)))

    def file_url(self, name: str) -> str:
        """A URL (or local path) of ``name`` that `read_url` understands."""
        return self.fs.unstrip_protocol(self._path(name)) if "://" in self.url else self._path(name)
