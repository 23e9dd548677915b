"""Which process holds a piece of work, and whether it is certainly gone.

An owner is ``host:pid:start``, the start being the process's start time in
clock ticks since boot (``/proc/PID/stat``), so a pid the kernel has since
given to another process is not taken for the one that held the work. Only a
process on this host can be known to be gone; elsewhere the work's own
heartbeat has to say it. "This host" is the host name: containers that see
each other's work must not share one (Docker gives each its own by default).
"""

from __future__ import annotations

import os
import socket


def _start_ticks(pid: int) -> str | None:
    """The process's start time (ticks since boot) and None if it is no more (or a zombie)."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii") as fh:
            fields = fh.read().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return None if fields[0] == "Z" else fields[19]


def this_process() -> str:
    """This process as an owner: ``host:pid:start``."""
    pid = os.getpid()
    return f"{socket.gethostname()}:{pid}:{_start_ticks(pid) or '?'}"


def gone(owner: str | None) -> bool:
    """True when ``owner`` ran on this host and that process has ended (or its pid is another's)."""
    try:
        host, pid, start = (owner or "").rsplit(":", 2)
        number = int(pid)
    except ValueError:
        return False
    if host != socket.gethostname():
        return False
    now = _start_ticks(number)
    return now is None or (start != "?" and now != start)
