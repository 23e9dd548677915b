"""`make run` passes every port camcal up listens on, and a port in use names the make variable to change.

The real `make run` of the repository's Makefile, in a subprocess, with this test's Python
environment as its venv (``VENV=``; its install step taken as done, ``-o``). Each port in turn is
held by another socket: `camcal up` must stop at once (exit 3, make's own status 2) naming that
port and the variable that sets it. Before, INGEST_PORT and EVENTS_PORT were not passed at all:
`make run` listened on 5555/5556 whatever the user set, after telling them to change those ports.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from tests.utils.system import REPO, free_ports, holding, kill_tree, marked_env, tree

pytestmark = pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")

VARIABLES = {"http": "PORT", "ingest": "INGEST_PORT", "events": "EVENTS_PORT"}


@pytest.mark.parametrize("held", ["ingest", "events", "http"])
def test_make_run_passes_each_port_and_a_port_in_use_names_its_variable(held: str, tmp_path: Path) -> None:
    ports = dict(zip(("http", "ingest", "events"), free_ports(3), strict=True))
    venv = Path(sys.prefix)
    mark = uuid.uuid4().hex
    args = [
        "make", "--no-print-directory", "-C", str(REPO), "-o", f"{venv}/.installed", "run",
        f"VENV={venv}", f"DATA={tmp_path / 'data'}",
        *(f"{VARIABLES[k]}={p}" for k, p in ports.items()),
    ]  # fmt: skip
    try:
        with holding(ports[held]):
            # On a Makefile that drops a port, camcal up starts whole on the default one: the
            # timeout ends that (and fails the test), and the mark finds what it started.
            env = {k: v for k, v in marked_env(mark).items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}
            proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=120)
    finally:
        kill_tree(mark)
    out = " ".join((proc.stdout + proc.stderr).split())
    assert proc.returncode == 2, out  # make's status when its recipe failed (camcal up: 3)
    assert "Error 3" in out, out
    assert f"cannot listen on 127.0.0.1:{ports[held]}" in out, out
    assert f"make run {VARIABLES[held]}=" in out, out
    assert "camcal is up" not in out and "Traceback" not in out, out
    assert not tree(mark)
