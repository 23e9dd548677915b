"""Writing a frame set (``docs/frameset.md``): images first, each row after its image, on a card
that may fill up or lose power at any moment; `camcal.core.frameset` reads what this writes."""

from __future__ import annotations

import contextlib
import csv
import io
import json
from pathlib import Path
from typing import TextIO

import numpy as np

from camcal.core.files import AppendLog, fsync_dir, write_atomic
from camcal.core.frameset import (
    MANIFEST,
    MANIFEST_COLUMNS,
    SETUP,
    FrameSetError,
    ManifestRow,
    Setup,
    decode_text,
    parse_manifest,
)
from camcal.core.images import encode_png


class FrameSetWriter:
    """Appends frames to a frame set: image first (atomically), then its manifest row.

    The manifest is opened in append mode and flushed after every row, so an
    interrupted writer leaves a valid frame set holding every frame whose row
    was written. Re-opening an existing folder continues its manifest.
    """

    def __init__(self, folder: Path, setup: Setup | None = None, *, fsync: bool = False) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.fsync = fsync
        if setup is not None:
            write_atomic(
                self.folder / SETUP, (json.dumps(setup.to_json(), indent=2) + "\n").encode(), fsync=fsync
            )
        manifest = self.folder / MANIFEST
        new = not manifest.exists() or manifest.stat().st_size == 0
        # Continue an existing manifest in its own columns (it may predate a new optional one),
        # read once (`decode_text`: the writer can still append to a manifest with a damaged byte).
        text = "" if new else decode_text(manifest.read_bytes())
        self._columns = list(MANIFEST_COLUMNS) if new else _header(text)
        self._log = AppendLog(manifest, fsync=fsync, newline="")  # a row whole or not at all
        if new:
            self._log.append(lambda fh: self._csv(fh).writeheader())
        self._count = 0 if new else len(parse_manifest(text, str(manifest)))

    def add(self, frame: np.ndarray | bytes, row: ManifestRow) -> ManifestRow:
        """Store one frame (array or encoded PNG bytes) under ``row.file`` and record it.

        With ``fsync`` the order is what survives a power cut: the image's bytes (fsync), its name
        (rename, then fsync of its folder, and of the folder above when the image's folder is new),
        then its manifest row (fsync). A row on the card thus always names a whole image; an image
        without a row is not part of the set.
        """
        data = frame if isinstance(frame, bytes) else encode_png(frame)
        target = self.folder / row.file
        new_dir = not target.parent.is_dir()
        target.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(target, data, fsync=self.fsync)
        if self.fsync:
            fsync_dir(target.parent)
            if new_dir:
                fsync_dir(target.parent.parent)
        try:
            return self.record(row)
        except OSError:
            with contextlib.suppress(OSError):
                target.unlink()  # an image without its row is not part of the set
            raise

    def record(self, row: ManifestRow) -> ManifestRow:
        """Append the manifest row of an image already stored under ``row.file``.

        Raises `FrameSetError` if the row has a value for a column the
        continued manifest lacks, rather than dropping the value.
        """
        values = row.to_csv()
        lost = [c for c, v in values.items() if v and c not in self._columns]
        if lost:
            raise FrameSetError(
                f"{self.folder / MANIFEST}: has no column {', '.join(lost)} for the values of {row.file}"
            )
        self._log.append(lambda fh: self._csv(fh).writerow(values))
        self._count += 1
        return row

    def _csv(self, fh: TextIO) -> csv.DictWriter[str]:
        return csv.DictWriter(fh, fieldnames=self._columns, extrasaction="ignore")

    def __len__(self) -> int:
        return self._count

    def close(self) -> None:
        self._log.close()

    def __enter__(self) -> FrameSetWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _header(text: str) -> list[str]:
    """Column names of a manifest's text."""
    return [h.strip() for h in next(csv.reader(io.StringIO(text, newline="")), [])]
