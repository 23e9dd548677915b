"""`camcal ingest` and `camcal serve` alone behave like daemons too; `camcal doctor` finds what was left.

Real processes and real signals; what is left of a tree is read from /proc
(`tests.utils.system.tree`).
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import time
import uuid
from pathlib import Path

import httpx
import zmq

from tests.utils.pace import Pace
from tests.utils.system import (
    assert_ports_free,
    free_ports,
    gone_within,
    holding,
    kill_tree,
    marked_env,
    run_camcal,
    tree,
    wait_until,
)


def test_a_port_in_use_stops_camcal_ingest_and_camcal_serve_at_once(tmp_path: Path) -> None:
    port, events, http = free_ports(3)
    mark = uuid.uuid4().hex
    data = str(tmp_path / "data")
    pace = Pace()  # "at once": seconds of an idle machine, stretched by how busy this one is
    with holding(port):
        code, out, took_s = run_camcal(
            ["ingest", "--data", data, "--bind", f"tcp://*:{port}", "--events", f"tcp://127.0.0.1:{events}"],
            mark,
            tmp_path,
        )
    print(f"camcal ingest with its port taken: exit {code} after {took_s:.1f} s")
    line = " ".join(out.split())
    assert code == 3 and took_s < pace.bound(10), (took_s, str(pace), out)
    assert f"the ingest cannot listen on 0.0.0.0:{port}: the port is in use by pid {os.getpid()}" in line
    assert "--bind (CAMCAL_INGEST_BIND)" in line and "Traceback" not in out
    assert not tree(mark)

    with holding(http):
        code, out, took_s = run_camcal(["serve", "--data", data, "--port", str(http)], mark, tmp_path)
    print(f"camcal serve with its port taken: exit {code} after {took_s:.1f} s")
    line = " ".join(out.split())
    assert code == 3 and took_s < pace.bound(10), (took_s, str(pace), out)
    assert f"the dashboard cannot listen on 127.0.0.1:{http}: the port is in use by pid {os.getpid()}" in line
    assert "--port (CAMCAL_HTTP_PORT)" in line
    assert not tree(mark)


def test_a_damaged_database_stops_ingest_serve_and_up_with_one_line_that_says_what_to_do(
    tmp_path: Path,
) -> None:
    """camcal.db is not a database (a damaged disk, a file put in its place): before, `camcal
    serve` printed uvicorn's traceback and the ingest SQLAlchemy's; now each says it in one line."""
    port, events, http = free_ports(3)
    mark = uuid.uuid4().hex
    data = tmp_path / "data"
    data.mkdir()
    (data / "camcal.db").write_bytes(b"not a database, only bytes " * 400)
    ingest = ["ingest", "--data", str(data), "--bind", f"tcp://127.0.0.1:{port}"]
    serve = ["serve", "--data", str(data), "--port", str(http)]
    up = ["up", "--data", str(data), "--port", str(http), "--ingest-port", str(port)]
    for args in (
        [*ingest, "--events", f"tcp://127.0.0.1:{events}"],
        serve,
        [*up, "--events-port", str(events)],
    ):
        code, out, _ = run_camcal(args, mark, tmp_path)
        line = " ".join(out.split())
        assert code == 3 and "Traceback" not in out, (args[0], out)
        assert f"the database {data / 'camcal.db'} cannot be opened (file is not a database)" in line, args[0]
        assert "move it aside" in line and "camcal import" in line, args[0]
        assert not tree(mark)


def health_report(events_port: int, timeout_s: float) -> dict:
    """The next health report the ingest publishes."""
    ctx = zmq.Context.instance()
    sub = ctx.socket(zmq.SUB)
    sub.setsockopt(zmq.SUBSCRIBE, b"health")
    sub.setsockopt(zmq.LINGER, 0)
    sub.connect(f"tcp://127.0.0.1:{events_port}")
    try:
        assert sub.poll(int(timeout_s * 1000)), f"no health report in {timeout_s} s"
        return json.loads(sub.recv_multipart()[1])["payload"]
    finally:
        sub.close(0)


def test_nothing_of_camcal_ingest_and_its_worker_pool_outlives_it(tmp_path: Path) -> None:
    """SIGKILL, SIGTERM, SIGINT in turn, on the same ports: each time the ingest, its fork server,
    workers and resource tracker are gone within 5 s (of an idle machine; `Pace`), and the next
    ingest starts there at once."""
    port, events = free_ports(2)
    for ending in (signal.SIGKILL, signal.SIGTERM, signal.SIGINT):
        mark = uuid.uuid4().hex
        log = tmp_path / f"ingest-{ending.name}.log"
        with log.open("wb") as out:
            proc = subprocess.Popen(
                [sys.executable, "-c", "from camcal.cli import main; main()", "ingest",
                 "--data", str(tmp_path / "data"), "--bind", f"tcp://127.0.0.1:{port}",
                 "--events", f"tcp://127.0.0.1:{events}", "--workers", "2", "--plaintext"],
                env=marked_env(mark), stdout=out, stderr=subprocess.STDOUT,
            )  # fmt: skip
        try:
            health_report(events, 30)
            # the ingest, its resource tracker, fork server and two workers
            wait_until(lambda m=mark: len(tree(m)) >= 5, 30, "the worker pool")
            pace = Pace()
            t0 = time.monotonic()
            proc.send_signal(ending)
            if ending != signal.SIGKILL:
                assert proc.wait(pace.bound(10)) == 0, log.read_text()[-2000:]
                assert "ingest stopped cleanly" in log.read_text()
            gone_within(mark, pace.bound(5.0) - (time.monotonic() - t0))
            gone_s = time.monotonic() - t0
            print(f"{ending.name}: the ingest and its pool gone {gone_s:.2f} s after it ({pace})")
            assert_ports_free(port, events)
        finally:
            kill_tree(mark)
            proc.wait(10)


def test_exit_statuses_are_documented() -> None:
    """Every status a long-running command exits with is in docs/operations.md, with its meaning."""
    from camcal.core import supervise

    doc = (Path(__file__).resolve().parents[2] / "docs" / "operations.md").read_text()
    for name in ("EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_NOT_STARTED"):
        code = getattr(supervise, name)
        assert re.search(rf"^\| {code} \| ", doc, flags=re.M), f"exit status {code} ({name}) undocumented"


def test_camcal_up_tells_systemd_when_it_is_ready_and_doctor_finds_what_it_left(tmp_path: Path) -> None:
    """`Type=notify`: READY=1 comes from camcal up itself (NotifyAccess=main) once the dashboard answers
    and the ingest publishes. `camcal doctor` lists its processes and their ports; when camcal up is
    killed while its ingest is frozen (SIGSTOP), doctor flags the ingest as left behind, and the ingest
    ends as soon as it runs again (the parent-death signal waited for it)."""
    notify = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    notify.bind(str(tmp_path / "notify"))
    notify.setsockopt(socket.SOL_SOCKET, socket.SO_PASSCRED, 1)
    http, ingest, events = free_ports(3)
    mark = uuid.uuid4().hex
    proc = subprocess.Popen(
        [sys.executable, "-c", "from camcal.cli import main; main()", "up", "--no-simulate",
         "--data", str(tmp_path / "data"), "--port", str(http), "--ingest-port", str(ingest),
         "--events-port", str(events)],
        env={**marked_env(mark), "NOTIFY_SOCKET": str(tmp_path / "notify")},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        notify.settimeout(60)
        data, ancillary, _, _ = notify.recvmsg(4096, socket.CMSG_SPACE(struct.calcsize("3i")))
        creds = next(d for _, kind, d in ancillary if kind == socket.SCM_CREDENTIALS)
        sender = struct.unpack("3i", creds[: struct.calcsize("3i")])[0]
        assert sender == proc.pid and data.startswith(b"READY=1"), (sender, data)
        # ready means ready: at this moment the dashboard answers and the ingest publishes
        assert httpx.get(f"http://127.0.0.1:{http}/healthz", timeout=5).status_code == 200
        assert health_report(events, 5)["modules"] == {}

        zmq_ports = f"holds port {min(ingest, events)}, {max(ingest, events)}"
        ingest_pid = next(p for p in tree(mark) if b"\0ingest\0" in Path(f"/proc/{p}/cmdline").read_bytes())
        rows = doctor_rows(tmp_path)
        assert f"camcal up (parent {os.getpid()}" in rows[proc.pid] and f"holds port {http}" in rows[proc.pid]
        assert rows[ingest_pid].startswith("ok") and zmq_ports in rows[ingest_pid]
        assert f"camcal ingest (parent {proc.pid}" in rows[ingest_pid]

        os.kill(ingest_pid, signal.SIGSTOP)
        proc.kill()
        proc.wait(10)
        row = doctor_rows(tmp_path)[ingest_pid]
        assert row.startswith("warn") and f"left behind: its camcal up (pid {proc.pid}) is gone" in row, row
        assert zmq_ports in row and f"kill {ingest_pid}" in row
        pace = Pace()
        t0 = time.monotonic()
        os.kill(ingest_pid, signal.SIGCONT)
        gone_within(mark, pace.bound(5.0))
        print(f"a frozen ingest whose camcal up was killed: gone {time.monotonic() - t0:.2f} s after SIGCONT")
        assert_ports_free(http, ingest, events)
    finally:
        notify.close()
        kill_tree(mark)
        proc.wait(10)


def doctor_rows(cwd: Path) -> dict[int, str]:
    """``camcal doctor --check processes``: its rows by pid, as "status detail"."""
    code, out, _ = run_camcal(["doctor", "--check", "processes"], uuid.uuid4().hex, cwd)
    assert code == 0, out
    rows = {}
    for line in out.splitlines():
        cells = [c.strip() for c in line.split("│")]
        if len(cells) >= 4 and cells[1].startswith("process "):
            rows[int(cells[1].split()[1])] = f"{cells[2]} {cells[3]}"
    return rows
