"""`camcal up` as a service manager stops it: SIGTERM (docker stop, systemd) ends every process it started."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import httpx

from tests.utils.system import _children, camcal_up, wait_until


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    stat = Path(f"/proc/{pid}/stat")
    return stat.exists() and stat.read_text().rsplit(")", 1)[1].split()[0] != "Z"  # not a zombie


def test_sigterm_stops_the_ingest_and_the_modules_before_camcal_up_exits(tmp_path: Path) -> None:
    with camcal_up(tmp_path / "data") as system:
        proc = system.process
        children = _children(proc.pid)
        assert len(children) == 3, children  # the ingest and two simulated modules
        wait_until(
            lambda: (
                {
                    m["link"]
                    for m in httpx.get(system.url("/api/health"), timeout=5).json()["modules"].values()
                }
                == {"up"}
            ),
            60,
            "both modules linked",
        )
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(60) == 0
        deadline = time.monotonic() + 10
        while any(alive(pid) for pid in children) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not [pid for pid in children if alive(pid)], "left running after camcal up exited"
        log = system.log.read_text()
        assert "stopped: ingest (0), module A (0), module B (0)" in log, log[-2000:]
