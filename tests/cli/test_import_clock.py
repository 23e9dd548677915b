"""An SD card of a module whose clock was never set: `camcal import` says how to import it, and
imports it at the right times with the offset the ship's clock alarm named.

The card is written by the module's own outbox (frames and sensor batches stamped by a clock that
reads 1970, as a Raspberry Pi's does without its clock's battery); `camcal import` runs as a real
process on a real SQLite store.
"""

from __future__ import annotations

import sqlite3
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from camcal.core import wire
from camcal.core.images import encode_png
from lrm.outbox import Outbox
from tests.utils.live import camcal_cli
from tests.utils.sim import SMALL_CAMERA, renderer

TRUE_START = datetime(2026, 11, 27, 9, 0, tzinfo=UTC)
#: The module's clock at TRUE_START: never set, it counted from 1970-01-01 at its boot.
READ_START = datetime(1970, 1, 1, 0, 5, tzinfo=UTC)
OFFSET_S = (READ_START - TRUE_START).total_seconds()  # ahead of true time: negative, it is behind


def card_of_a_clock_never_set(root: Path, n: int = 4) -> Path:
    card = root / "card"
    box = Outbox(card, "B", fsync=False)
    render = renderer("trex", 41.62, far_side=True, camera=SMALL_CAMERA, camera_id="B")
    for i in range(n):
        pixels, _ = render.render(460, 0.05, 8.0, rng=np.random.default_rng(i))
        box.add_frame(
            "boot1",
            i + 1,
            encode_png(pixels),
            captured_at=READ_START + timedelta(seconds=10 * i),
            camera="B",
            wavelength_nm=460,
            exposure_s=0.05,
            gain_db=8.0,
            depth_m=3400.0,
            schedule_version=1,
        )
    t0 = READ_START.timestamp()
    rows = [[t0 + k, 4.0, 30.0, 0.1, 0.0, 9.8, 0.0, 0.0, 0.0, 3400.0] for k in range(3)]
    assert len(rows[0]) == len(wire.SENSOR_COLUMNS)
    box.add_sensors("boot1", n + 1, rows)
    box.close()
    return card


def test_a_card_stamped_1970_says_how_to_import_it_and_imports_at_the_true_times(tmp_path: Path) -> None:
    card = card_of_a_clock_never_set(tmp_path)
    res = camcal_cli("import", str(card), "--data", str(tmp_path / "plain"), "--dive", "d1")
    out = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0, out
    assert "0 frames imported" in out and "0 sensor batches" in out, out
    for words in ("captured at 1970-01-01 00:05 UTC", "which was not set", "--clock-offset", "B=-SECONDS"):
        assert words in out, (words, out)  # (the table wraps its lines)
    with sqlite3.connect(tmp_path / "plain" / "camcal.db") as db:
        assert db.execute("SELECT COUNT(*) FROM frames").fetchone() == (0,)  # nothing placed in 1970

    res = camcal_cli(
        "import",
        str(card),
        "--data",
        str(tmp_path / "fixed"),
        "--dive",
        "d1",
        f"--clock-offset=B={OFFSET_S:.0f}",
    )
    out = " ".join((res.stdout + res.stderr).split())
    assert res.returncode == 0 and "4 frames imported" in out and "1 sensor batches" in out, out
    with sqlite3.connect(tmp_path / "fixed" / "camcal.db") as db:
        times = [t for (t,) in db.execute("SELECT captured_unix_s FROM frames ORDER BY seq")]
        samples = [t for (t,) in db.execute("SELECT t_unix_s FROM sensor_samples ORDER BY t_unix_s")]
        ok = db.execute("SELECT COUNT(*) FROM frame_results WHERE status = 'ok'").fetchone()[0]
    start = TRUE_START.timestamp()
    assert np.allclose(times, [start + 10 * i for i in range(4)], atol=1e-3), times
    assert np.allclose(samples, [start + k for k in range(3)], atol=1e-3), samples
    assert ok == 4  # analysed as any frame
