"""What runs on this machine and which ports it holds, read from Linux's /proc.

Used to say who holds a port a camcal service wants (``camcal up``,
``camcal ingest``, ``camcal serve``) and to list camcal processes that were
left running (``camcal doctor``). Everything here degrades to "unknown" where
/proc is missing (not Linux) or a process belongs to a user this one cannot
inspect: it explains, it never decides.
"""

from __future__ import annotations

import contextlib
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

PROC = Path("/proc")
#: /proc/net/tcp state of a listening socket (a socket only bound is not listed there at all).
_LISTEN = "0A"


@dataclass(frozen=True)
class PortUse:
    """A local TCP port held by a listening socket."""

    port: int
    address: str
    uid: int
    inode: int


@dataclass
class Process:
    """One process: its command line, its parent, its start time, and the ports its sockets hold."""

    pid: int
    ppid: int
    pgid: int
    argv: list[str]
    started_unix_s: float | None
    ports: list[int] = field(default_factory=list)

    @property
    def command(self) -> str:
        return " ".join(self.argv)


def _hex_address(text: str) -> tuple[str, int]:
    addr, port = text.split(":")
    if len(addr) == 8:  # IPv4, little-endian
        raw = bytes.fromhex(addr)[::-1]
        host = ".".join(str(b) for b in raw)
    else:  # IPv6: four little-endian 32-bit words
        words = [bytes.fromhex(addr[i : i + 8])[::-1].hex() for i in range(0, 32, 8)]
        full = "".join(words)
        host = ":".join(full[i : i + 4] for i in range(0, 32, 4))
    return host, int(port, 16)


def port_uses(port: int | None = None) -> list[PortUse]:
    """Listening sockets on a local TCP port (all ports, or ``port``), from /proc/net/tcp and tcp6."""
    out = []
    for name in ("tcp", "tcp6"):
        try:
            lines = (PROC / "net" / name).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            cols = line.split()
            if len(cols) < 10 or cols[3] != _LISTEN:
                continue
            host, local = _hex_address(cols[1])
            _, remote = _hex_address(cols[2])
            if remote != 0 or (port is not None and local != port):
                continue
            out.append(PortUse(local, host, int(cols[7]), int(cols[9])))
    return out


def _socket_inodes(pid: int) -> set[int]:
    out: set[int] = set()
    try:
        fds = os.listdir(PROC / str(pid) / "fd")
    except OSError:
        return out
    for fd in fds:
        try:
            target = os.readlink(PROC / str(pid) / "fd" / fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            out.add(int(target[8:-1]))
    return out


def boot_time_unix_s() -> float | None:
    try:
        for line in (PROC / "stat").read_text().splitlines():
            if line.startswith("btime "):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def process(pid: int, boot_unix_s: float | None = None) -> Process | None:
    """The process ``pid``, or None if it is gone (or a zombie)."""
    try:
        stat = (PROC / str(pid) / "stat").read_text()
        argv = (PROC / str(pid) / "cmdline").read_bytes().split(b"\0")
    except OSError:
        return None
    # pid (comm) state ppid ...: comm may hold spaces, so split after the last ')'.
    fields = stat.rsplit(")", 1)[1].split()
    if fields[0] == "Z":
        return None
    started = None
    if boot_unix_s is not None:
        started = boot_unix_s + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    words = [a.decode(errors="replace") for a in argv if a]
    return Process(pid, int(fields[1]), int(fields[2]), words, started)


def processes() -> list[Process]:
    """Every process this user can see (zombies left out)."""
    boot = boot_time_unix_s()
    out = []
    for entry in PROC.iterdir() if PROC.is_dir() else []:
        if entry.name.isdigit():
            p = process(int(entry.name), boot)
            if p is not None:
                out.append(p)
    return out


def busy_factor() -> float:
    """How many processes want each core now (at least 1): the 1-minute load average and the
    processes runnable at this instant (this one left out), per core. A part that stops in 2 s on an
    idle machine takes about this many times longer on a busy one."""
    cores = os.cpu_count() or 1
    try:
        load1 = os.getloadavg()[0]
    except OSError:
        load1 = 0.0
    running = 1
    with contextlib.suppress(OSError, ValueError, IndexError):
        running = int((PROC / "loadavg").read_text().split()[3].split("/")[0])
    return max(1.0, load1 / cores, (running - 1) / cores)


def alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie, dead but not yet reaped, counts as gone)."""
    return process(pid) is not None


def descendants(pid: int) -> list[int]:
    """The processes below ``pid``: its children, theirs, and so on."""
    by_parent: dict[int, list[int]] = {}
    for p in processes():
        by_parent.setdefault(p.ppid, []).append(p.pid)
    out, todo = [], [pid]
    while todo:
        for child in by_parent.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def group(pgid: int) -> list[int]:
    """The live processes of process group ``pgid`` (a child started in its own session and its helpers)."""
    return [p.pid for p in processes() if p.pgid == pgid]


def with_ports(procs: list[Process]) -> list[Process]:
    """``procs`` with the ports their sockets listen on filled in."""
    uses = {u.inode: u.port for u in port_uses()}
    for p in procs:
        p.ports = sorted({uses[i] for i in _socket_inodes(p.pid) if i in uses})
    return procs


def holders(port: int) -> tuple[list[Process], list[PortUse]]:
    """Who holds TCP ``port``: the processes found, and the sockets (with their owner's uid)."""
    uses = port_uses(port)
    inodes = {u.inode for u in uses}
    found = []
    if inodes:
        for p in processes():
            if _socket_inodes(p.pid) & inodes:
                p.ports = [port]
                found.append(p)
    return found, uses


def describe_holder(port: int) -> str:
    """``"pid 4242 (python3 -m http.server 5555)"``: what holds ``port``, as far as this user can tell."""
    found, uses = holders(port)
    if found:
        return ", ".join(f"pid {p.pid} ({short(p.command)})" for p in found)
    if uses:
        owners = sorted({u.uid for u in uses})
        who = "this user" if owners == [os.getuid()] else f"uid {', '.join(str(u) for u in owners)}"
        return f"a process of {who} that cannot be inspected from here"
    return ""


def short(command: str, limit: int = 90) -> str:
    return command if len(command) <= limit else command[: limit - 1] + "…"


def age_s(p: Process) -> float | None:
    return None if p.started_unix_s is None else max(0.0, time.time() - p.started_unix_s)


@dataclass
class CamcalProcess:
    """A process of camcal: what it is, and why it looks left behind (empty if it does not)."""

    process: Process
    kind: str
    leftover: str = ""
    args: str = ""  # a camcal command's words after ``camcal``
    installation: Path | None = None  # the venv it runs from, where that can be told (`installation`)


def _environ(pid: int) -> dict[str, str]:
    try:
        raw = (PROC / str(pid) / "environ").read_bytes()
    except OSError:
        return {}
    out = {}
    for item in raw.split(b"\0"):
        key, sep, value = item.partition(b"=")
        if sep:
            out[key.decode(errors="replace")] = value.decode(errors="replace")
    return out


def _kind(p: Process) -> tuple[str, str] | None:
    """``("camcal ingest", "ingest --data ...")``, ``("analysis fork server", "")``, ...;
    None if ``p`` is no camcal process."""
    text = p.command
    if "multiprocessing.forkserver" in text and "camcal" in text:
        return "analysis fork server", ""
    if "multiprocessing.resource_tracker" in text:
        return "resource tracker", ""
    argv = p.argv
    for i, word in enumerate(argv[:3]):  # the interpreter, then a script, -m camcal or -c "..."
        entry = (
            word.endswith("/camcal")
            or "camcal.cli import main" in word
            or (word == "camcal" and (i == 0 or argv[i - 1] == "-m"))
        )
        if entry:
            words = [w for w in argv[i + 1 :] if not w.startswith("-")][:2]
            sub = words[0] if words else ""
            kind = f"camcal {sub} {words[1]}" if sub == "lrm" and len(words) > 1 else f"camcal {sub}".strip()
            return kind, " ".join(argv[i + 1 :])
    return None


def installation(p: Process) -> Path | None:
    """The Python environment (venv) ``p`` runs from: the folder above the ``bin/`` of its interpreter
    or script when a ``pyvenv.cfg`` marks it; None when that cannot be told (a system interpreter,
    a process of another user)."""
    try:
        cwd = os.readlink(PROC / str(p.pid) / "cwd")
    except OSError:
        cwd = None
    for word in p.argv[:2]:
        if "/" not in word or (cwd is None and not word.startswith("/")):
            continue
        path = Path(
            os.path.normpath(os.path.join(cwd or "/", word))
        )  # never resolved: a venv's python is a link
        root = path.parent.parent
        if path.parent.name == "bin" and (root / "pyvenv.cfg").is_file():
            return root.resolve()
    return None


def camcal_processes() -> list[CamcalProcess]:
    """camcal's processes on this machine, with the ports they hold and those that look left behind.

    Left behind: a child of ``camcal up`` whose ``camcal up`` is gone (its
    environment names it), or a worker-pool helper (fork server, worker,
    resource tracker) whose owner is gone.
    """
    procs = {p.pid: p for p in processes()}
    found: dict[int, CamcalProcess] = {}
    for p in procs.values():
        named = _kind(p)
        if named is not None and p.pid != os.getpid():
            found[p.pid] = CamcalProcess(p, named[0], args=named[1])
    # resource trackers only count when they belong to a camcal process's group
    groups = {c.process.pgid for c in found.values() if c.kind != "resource tracker"}
    for pid in [pid for pid, c in found.items() if c.kind == "resource tracker"]:
        if found[pid].process.pgid not in groups:
            del found[pid]
    for c in found.values():
        p = c.process
        c.installation = installation(p)
        parent = found.get(p.ppid)
        if c.kind == "analysis fork server" and parent is not None and parent.kind == c.kind:
            c.kind = "analysis worker"
        supervisor = _environ(p.pid).get("CAMCAL_SUPERVISOR_FD", "")
        owner = supervisor.partition(",")[2]
        if owner.isdigit() and int(owner) != p.ppid:
            c.leftover = f"its camcal up (pid {owner}) is gone"
        elif c.kind in ("analysis fork server", "resource tracker") and parent is None:
            c.leftover = "the process it served is gone"
    with_ports([c.process for c in found.values()])
    return sorted(found.values(), key=lambda c: c.process.pid)
