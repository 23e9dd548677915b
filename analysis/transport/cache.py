"""A directory of computed template pieces, one ``.npz`` file per piece.

The only file access in `analysis`: a compute cache, not storage. Each file is
named by a hash of everything that determined it, holds plain arrays and a
JSON description (never pickles), and is written to a temporary name and
renamed, so a crash or a second process never leaves a half-written file.
Nothing is read or created at import; the directory is chosen by the caller,
else by ``CAMCAL_CACHE_DIR``, else ``~/.cache/camcal/templates``.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

#: Environment variable naming the template cache directory.
CACHE_ENV = "CAMCAL_CACHE_DIR"
#: Bumped whenever the content of cached pieces changes meaning.
CACHE_VERSION = 2


def default_cache_dir() -> Path:
    """``$CAMCAL_CACHE_DIR`` if set, else ``~/.cache/camcal/templates``."""
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "camcal" / "templates"


def cache_key(kind: str, description: Mapping[str, Any]) -> str:
    """A file stem for a piece: its kind and a hash of its JSON description."""
    text = json.dumps({"kind": kind, "version": CACHE_VERSION, **description}, sort_keys=True)
    return f"{kind}-{hashlib.sha256(text.encode()).hexdigest()[:20]}"


class TemplateCache:
    """Load-or-compute of named array bundles in one directory.

    ``directory=None`` means `default_cache_dir`; ``enabled=False`` computes
    every time (tests of the computation itself, or a read-only disk).
    """

    def __init__(self, directory: Path | str | None = None, *, enabled: bool = True) -> None:
        self.directory = Path(directory).expanduser() if directory is not None else default_cache_dir()
        self.enabled = enabled

    def path(self, key: str) -> Path:
        return self.directory / f"{key}.npz"

    def load(self, key: str) -> dict[str, np.ndarray] | None:
        """The arrays stored under ``key``, or None if absent or unreadable."""
        if not self.enabled:
            return None
        path = self.path(key)
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                return {name: data[name] for name in data.files}
        except (OSError, ValueError, EOFError):
            return None  # a damaged file is recomputed and overwritten

    def save(self, key: str, arrays: Mapping[str, np.ndarray], description: Mapping[str, Any]) -> None:
        """Store ``arrays`` (and the JSON description) under ``key``, atomically."""
        if not self.enabled:
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        payload = {**arrays, "description": np.array(json.dumps(description, sort_keys=True))}
        fd, tmp = tempfile.mkstemp(dir=self.directory, prefix=f".{key}.", suffix=".npz")
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez_compressed(fh, **payload)  # type: ignore[arg-type]
            os.replace(tmp, self.path(key))
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    def get(
        self,
        key: str,
        description: Mapping[str, Any],
        compute: Callable[[], Mapping[str, np.ndarray]],
    ) -> dict[str, np.ndarray]:
        """The cached arrays of ``key``, computing and storing them on a miss."""
        found = self.load(key)
        if found is not None:
            found.pop("description", None)
            return found
        arrays = dict(compute())
        self.save(key, arrays, description)
        return arrays
