"""`camcal doctor` checks the system that runs, as it runs, and disturbs nothing.

A real `camcal up` started with port options only (no environment variable repeats them), and
the real `camcal doctor` in a subprocess. Before, doctor checked the default ports (FAIL: "nothing
listens", "no heartbeat", "does not answer") and, pointed at the right ones, probed the modules'
port with a bare TCP connection that the ingest counted (and the deck page showed) as a refused
connection with a broken handshake. It also told the user to `kill` the processes of another camcal
installation on the machine (a colleague's checkout) because they looked left behind.
"""

from __future__ import annotations

import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx

from tests.utils.system import SHORT_DIVE, camcal_up, kill_tree, marked_env, run_camcal, wait_until


def refused_total(base_url: str) -> int:
    return int(
        (httpx.get(f"{base_url}/api/health", timeout=10).json().get("refused_connections") or {})["total"]
    )


def doctor(cwd: Path, env: dict[str, str] | None = None) -> tuple[int, str]:
    """``camcal doctor`` as a user runs it where they ran `make run` (its data: ./camcal-data)."""
    mark = uuid.uuid4().hex
    if env is None:
        code, out, _ = run_camcal(["doctor"], mark, cwd)
        return code, " ".join(out.replace("│", " ").split())
    proc = subprocess.run(
        [sys.executable, "-c", "from camcal.cli import main; main()", "doctor"],
        cwd=cwd,
        env={**marked_env(mark), "COLUMNS": "400", **env},
        capture_output=True,
        text=True,
        timeout=120,
    )
    return proc.returncode, " ".join((proc.stdout + proc.stderr).replace("│", " ").split())


def test_doctor_checks_the_running_systems_own_ports_and_refuses_no_connection(tmp_path: Path) -> None:
    # on deck for the whole test (a long deck time): both modules linked, no frames to analyse
    with camcal_up(tmp_path / "camcal-data", dive={**SHORT_DIVE, "--deck-s": "6000"}) as system:
        http, ingest, events = system.ports
        wait_until(lambda: httpx.get(system.url("/api/health"), timeout=5).json()["refused_connections"], 30,
                   "the ingest's refused-connection count on /api/health")  # fmt: skip
        before = refused_total(system.base_url)

        # 1. Nothing in the environment: the run file in the data folder says what runs where.
        code, out = doctor(tmp_path)
        assert code == 0, out
        assert "FAIL" not in out, out
        assert f"camcal up (pid {system.process.pid}" in out, out
        assert f"http_port {http} (your settings: 8000)" in out, out
        assert f"ingest port ok {ingest} is listened on" in out, out
        assert "heartbeat received" in out and f"http://127.0.0.1:{http}/api/health answers" in out, out
        assert "the running dashboard lets in: tester" in out, out

        # 2. The environment names the same ports (as the old doctor needed): still looked at, never
        #    connected to. The ingest counts refused connections as they happen; two heartbeats later
        #    its count has not moved.
        code, out = doctor(
            tmp_path,
            {
                "CAMCAL_HTTP_PORT": str(http),
                "CAMCAL_INGEST_BIND": f"tcp://127.0.0.1:{ingest}",
                "CAMCAL_EVENTS_CONNECT": f"tcp://127.0.0.1:{events}",
            },
        )
        assert code == 0 and "FAIL" not in out, out
        time.sleep(2.5)
        assert refused_total(system.base_url) == before, "doctor's probe was counted as a refused connection"
    # camcal up removed its run file as it stopped: doctor no longer sees it
    assert not list((system.data / "run").glob("up-*.json"))


def test_doctor_never_tells_to_kill_another_installations_processes(tmp_path: Path) -> None:
    """A camcal process of another venv that looks left behind (its `camcal up` is gone) is named as
    another installation's, with no `kill` advice; it is not this doctor's to stop."""
    other = tmp_path / "colleague" / ".venv"
    (other / "bin").mkdir(parents=True)
    (other / "pyvenv.cfg").write_text((Path(sys.prefix) / "pyvenv.cfg").read_text())
    (other / "bin" / "python").symlink_to(Path(sys.executable).resolve())
    gone = subprocess.Popen(["true"])
    gone.wait()
    mark = uuid.uuid4().hex
    env = {**marked_env(mark), "CAMCAL_SUPERVISOR_FD": f"3,{gone.pid}"}  # its camcal up: gone
    # it sleeps, but looks like camcal to /proc (its command line names camcal's entry point)
    code_text = "import time; time.sleep(120)  # from camcal.cli import main; main()"
    proc = subprocess.Popen([str(other / "bin" / "python"), "-c", code_text], env=env, cwd=tmp_path)
    try:
        code, out, _ = run_camcal(["doctor", "--check", "processes"], mark, tmp_path)
        out = " ".join(out.replace("│", " ").split())
        assert code == 0, out
        assert f"kill {proc.pid}" not in out, out
        assert f"of another installation ({other.resolve()})" in out, out
        assert "not this one's to stop" in out, out
        assert f"process {proc.pid}" not in out, out  # counted under its installation, not listed to act on
    finally:
        proc.kill()
        proc.wait(10)
        kill_tree(mark)
