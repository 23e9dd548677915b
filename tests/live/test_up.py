"""`camcal up` behaves like a daemon: it fails fast, says why, and nothing of it outlives it.

Real processes and real signals throughout. What is left of a tree is read from
/proc by the mark every process of it carries in its environment
(`tests.utils.system.tree`), never from camcal's own bookkeeping.
"""

from __future__ import annotations

import os
import re
import signal
import time
import uuid
from pathlib import Path

import httpx
import pytest

from tests.utils.pace import Pace
from tests.utils.system import (
    System,
    assert_ports_free,
    camcal_up,
    free_ports,
    gone_within,
    holding,
    module_pid,
    run_camcal,
    tree,
    wait_until,
)


def test_a_port_in_use_stops_camcal_up_at_once_naming_the_holder_and_the_option(tmp_path: Path) -> None:
    http, ingest, events = free_ports(3)
    mark = uuid.uuid4().hex
    pace = Pace()
    with holding(ingest):
        code, out, took_s = run_camcal(
            ["up", "--data", str(tmp_path / "data"), "--port", str(http), "--ingest-port", str(ingest),
             "--events-port", str(events)],
            mark,
            tmp_path,
        )  # fmt: skip
        other_pid = os.getpid()
    print(f"camcal up with its ingest port taken: exit {code} after {took_s:.1f} s")
    assert code == 3, out
    assert took_s < pace.bound(10), (took_s, str(pace))  # at once: no part started first
    line = " ".join(out.split())
    assert f"ingest cannot listen on 127.0.0.1:{ingest}" in line, out
    assert f"by pid {other_pid}" in line and "--ingest-port" in line, out
    assert "camcal is up" not in out and "Traceback" not in out
    assert not tree(mark)


def test_a_part_that_fails_to_start_stops_every_part_started(tmp_path: Path) -> None:
    """The modules cannot start (an unknown schedule): the ingest and dashboard already run, and stop."""
    http, ingest, events = free_ports(3)
    mark = uuid.uuid4().hex
    pace = Pace()
    code, out, took_s = run_camcal(
        ["up", "--data", str(tmp_path / "data"), "--port", str(http), "--ingest-port", str(ingest),
         "--events-port", str(events), "--schedule", "no-such-schedule"],
        mark,
        tmp_path,
    )  # fmt: skip
    ended = time.time()
    print(f"camcal up whose modules cannot start: exit {code} after {took_s:.1f} s")
    assert code == 3, out
    line = " ".join(out.split())
    failed = re.search(r"camcal could not start: module ([AB]) exited with status 2 while starting", line)
    assert failed, out
    # it ended within 10 s of the module's failure (the module's last word in its log)
    failed_at = (tmp_path / "data" / "logs" / f"module-{failed.group(1)}.log").stat().st_mtime
    print(f"... {ended - failed_at:.1f} s after module {failed.group(1)} failed")
    assert ended - failed_at < pace.bound(10), (ended - failed_at, str(pace))
    assert "'no-such-schedule' is neither a preset" in line, out  # its log's last lines
    # the other module failed too, or was stopped while it started
    assert re.search(r"stopped: ingest \(0\), module A \((2|-15)\), module B \((2|-15)\)", line), out
    assert "camcal is up" not in out
    assert not tree(mark)
    assert_ports_free(http, ingest, events)


def streaming(system: System) -> bool:
    """Both modules linked and frames arriving from both (the ingest's own figures)."""
    try:
        modules = httpx.get(system.url("/api/health"), timeout=5).json()["modules"]
    except httpx.HTTPError:
        return False
    return all(
        modules.get(m, {}).get("link") == "up" and (modules[m].get("frames_last_min") or 0) > 0
        for m in ("A", "B")
    )


@pytest.mark.parametrize(
    "ending", ["SIGKILL", "SIGTERM", "SIGINT", "the ingest killed"], ids=lambda e: e.replace(" ", "-")
)
def test_nothing_of_camcal_up_outlives_it_and_its_ports_are_free_at_once(
    ending: str, tmp_path: Path, up_ports: tuple[int, int, int]
) -> None:
    """However `camcal up` ends, while its modules stream, its whole tree is gone within 5 s (of an
    idle machine: `tests.utils.pace.Pace` stretches it by how busy the machine is).

    All four endings run on the same ports one after the other: each `camcal up`
    starts at once where the last one ended.
    """
    dive = {"--speed": "20", "--frame-scale": "0.25", "--test-stop-s": "600"}  # at the first stop
    t_start = time.monotonic()
    with camcal_up(tmp_path / "data", dive=dive, ports=up_ports) as system:
        print(f"{ending}: camcal up said it was up {time.monotonic() - t_start:.1f} s after its start")
        wait_until(lambda: streaming(system), 60, "frames from both modules")

        def offsets() -> list[float | None]:  # each module's clock against the ship's, as the deck sees
            modules = httpx.get(system.url("/api/health"), timeout=5).json()["modules"]
            return [modules[m]["clock_offset_s"] for m in ("A", "B")]

        wait_until(
            lambda: None not in offsets(), Pace().bound(15), "the modules' clock offsets on /api/health"
        )
        assert all(abs(o) < 2.0 for o in offsets() if o is not None)  # one host: one clock
        members = tree(system.mark)
        # camcal up, the ingest, its fork server, resource tracker and worker(s), two modules
        assert len(members) >= 7, members
        proc = system.process
        pace = Pace()  # a daemon ends within seconds of its signal: seconds of an idle machine
        t0 = time.monotonic()
        if ending == "the ingest killed":
            ingest = next(c for c in members if b"\0ingest\0" in Path(f"/proc/{c}/cmdline").read_bytes())
            os.kill(ingest, signal.SIGKILL)
            assert proc.wait(pace.bound(10)) == 1
            assert "the ingest killed by SIGKILL; stopping camcal" in " ".join(system.log.read_text().split())
        else:
            module_pid(system, "A")  # the modules are there to stop
            proc.send_signal(getattr(signal, ending))
            if ending != "SIGKILL":
                assert proc.wait(pace.bound(10)) == 0
                assert "stopped: ingest (0), module A (0), module B (0)" in system.log.read_text()
        gone_within(system.mark, pace.bound(5.0) - (time.monotonic() - t0))
        gone_s = time.monotonic() - t0
        print(f"{ending}: every process of camcal up's tree gone {gone_s:.2f} s after it ({pace})")
        assert_ports_free(*up_ports)


@pytest.fixture(scope="module")
def up_ports() -> tuple[int, int, int]:
    """One set of ports for every `camcal up` of the module, one after the other."""
    ports = free_ports(3)
    return ports[0], ports[1], ports[2]
