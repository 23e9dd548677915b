"""A card that fills up in the middle of a manifest row: the row is taken back whole.

A real full file system (a 1 MB tmpfs; needs root, skipped otherwise). The module's contract
(`lrm.producing`): a frame the card cannot keep is not taken, and its sequence number goes to
the next frame. Before, the part of the row that did not fit stayed in the file's buffer and
reached the card with the next row: the card then held two rows with one number, the second
frame's image under the first one's values.
"""

from __future__ import annotations

import os
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from camcal.core.frameset import read_manifest
from camcal.core.images import encode_png
from lrm.outbox import Outbox
from tests.utils.tmpfs import fill, small_tmpfs

PAGE = 4096  # tmpfs gives a file its space a page at a time


def test_a_row_the_card_could_not_keep_is_taken_back_and_its_number_reused(tmp_path: Path) -> None:
    with small_tmpfs(tmp_path / "card", 1) as card:
        outbox = Outbox(card / "outbox", "A", fsync=True)
        manifest = card / "outbox" / "frames" / "manifest.csv"
        png = encode_png(np.zeros((4, 4), np.uint8))  # an image that fits in one page
        taken: list[int] = []
        refused: list[int] = []

        def take(wavelength_nm: int) -> None:
            seq = (taken[-1] if taken else 0) + 1  # a refused frame's number goes to the next one
            try:
                outbox.add_frame(
                    "b1", seq, png, captured_at=datetime.now(UTC), camera="A", wavelength_nm=wavelength_nm,
                    exposure_s=0.05, gain_db=2.0, depth_m=100.0, schedule_version=1,
                )  # fmt: skip
            except OSError:
                refused.append(seq)
                return
            taken.append(seq)

        # Rows until the manifest's last page has room for a few bytes only, not a row.
        while PAGE - manifest.stat().st_size % PAGE >= 60:
            take(405)
        filler = fill(card, leave_bytes=PAGE)  # one page free: the image fits, its row does not
        take(460)
        assert refused == [len(taken) + 1], "the card did not fill in the middle of a row"
        filler.unlink()
        take(525)
        take(525)

        rows = read_manifest(manifest.parent)
        assert [r.seq for r in rows] == taken == list(range(1, len(taken) + 1))
        assert all(r.error is None for r in rows)
        assert [r.wavelength_nm for r in rows[-2:]] == [525, 525]
        assert not any("_460_" in name for name in os.listdir(manifest.parent / "b1")), "its image stayed"
        # What a module restarted on this card offers the ship: every frame taken, each once.
        outbox.close()
        again = Outbox(card / "outbox", "A", fsync=True)
        assert [e.seq for e in again.pending()] == taken
        again.close()
