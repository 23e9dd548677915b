"""The bench commands on the real GigE Vision emulator: `camcal lrm cameras`, `snap` and `doctor`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from camcal.cli import app
from camcal.core.images import decode_frame_scaled
from tests.utils.aravis import FakeGigECamera, whole_ramp


@pytest.fixture
def gige():
    with FakeGigECamera() as cam:
        yield cam


def test_cameras_lists_the_emulator_and_snap_says_what_the_camera_applied(gige, tmp_path: Path) -> None:
    runner = CliRunner()
    listed = runner.invoke(app, ["lrm", "cameras", "--json"])
    assert listed.exit_code == 0, listed.output
    cams = {c["device_id"]: c for c in map(json.loads, listed.output.splitlines())}
    me = cams[gige.device_id]
    assert me["serial"] == gige.serial and "Mono16" in me["pixel_formats"]
    assert me["exposure_range_s"] == [1e-5, 10.0] and me["gain_range_db"] == [0.0, 10.0]

    out = tmp_path / "one.png"
    args = ["lrm", "snap", "--device", gige.serial, "--exposure-s", "0.0123456", "--gain-db", "3.4"]
    res = runner.invoke(app, [*args, "--out", str(out), "--width-px", "320", "--height-px", "240"])
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())
    assert "exposure 0.012345 s (asked 0.0123456), gain 3 dB (asked 3.4)" in text
    assert "320 x 240 px Mono8 (8 bits, full scale 255)" in text and "device clock" in text
    frame, top = decode_frame_scaled(out.read_bytes())
    assert frame.shape == (240, 320) and frame.dtype == np.uint8 and top == 255

    deep = tmp_path / "deep.png"
    res = runner.invoke(app, [*args, "--out", str(deep), "--pixel-format", "Mono16", "--width-px", "64"])
    assert res.exit_code == 0, res.output
    frame, top = decode_frame_scaled(deep.read_bytes())
    assert frame.dtype == np.uint16 and frame.shape == (2048, 64) and top == 65535

    jumbo = tmp_path / "jumbo.png"  # 8000 B packets (a GigE link with jumbo frames): the frame whole
    base = ["lrm", "snap", "--device", gige.serial, "--exposure-s", "0.01", "--gain-db", "0"]
    res = runner.invoke(app, [*base, "--out", str(jumbo), "--packet-size-b", "8000", "--height-px", "256"])
    assert res.exit_code == 0, res.output
    assert whole_ramp(decode_frame_scaled(jumbo.read_bytes())[0])

    bad = runner.invoke(
        app,
        [
            "lrm",
            "snap",
            "--device",
            "NOPE",
            "--exposure-s",
            "0.01",
            "--gain-db",
            "0",
            "--out",
            str(tmp_path / "x.png"),
        ],
    )
    assert bad.exit_code == 2 and "no GenICam camera 'NOPE'" in bad.output and gige.device_id in bad.output
    assert not (tmp_path / "x.png").exists()
    wide = runner.invoke(app, [*args, "--out", str(tmp_path / "y.png"), "--exposure-s", "20"])
    assert wide.exit_code == 1 and "outside the camera's range" in wide.output, wide.output


def test_doctor_checks_the_camera_keys_clock_card_and_ship(gige, tmp_path: Path) -> None:
    from ingest.service import IngestService
    from tests.live.conftest import ingest_config

    svc = IngestService(ingest_config(tmp_path / "data"))
    svc.start()
    try:
        args = [
            "lrm",
            "doctor",
            "--camera",
            f"aravis:{gige.serial}",
            "--plaintext",
            "--connect",
            svc.endpoint,
            "--outbox",
            str(tmp_path / "outbox"),
            "--timeout-s",
            "10",
        ]
        res = CliRunner().invoke(app, args)
        text = " ".join(res.output.split())
        assert "camera ok Aravis Fake" in text and "2048 x 2048 px, 8 bits" in text, text
        assert "ship ok" in text and "completes the link's handshake (plaintext)" in text
        assert "outbox" in text and "GB free" in text and "keys warning plaintext" in text
        assert res.exit_code == 0 or "clock" in text  # (this machine's clock may not be synchronised)
        assert not svc.links, "the doctor sent something to the ship"
        gige.kill()
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 1 and "camera FAIL" in " ".join(res.output.split())
    finally:
        svc.stop()
