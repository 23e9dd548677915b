"""Services that start, report and end together: ports checked, children tied to their parent.

A camcal service (``camcal up``, ``camcal ingest``, ``camcal serve``) is
started by tired people, systemd or Docker, and ended by Ctrl-C, SIGTERM, the
OOM killer or a power cut. This module gives them one way to behave:

* **Ports first.** `check_port` tries a port the way the service will bind
  it; if it is taken, `PortInUse` says which part wanted it, who holds it
  (from /proc, `camcal.core.procinfo`) and which setting to change.
* **Children report.** `Supervisor.spawn` starts a ``camcal`` command with one
  end of a socket pair; the child (`attach`, called first thing by the CLI)
  writes one JSON line on it when it is ready (`notify_ready`) or why it
  could not start (`notify_error`).
* **Children die with their parent.** The child asks the kernel for SIGTERM
  when its parent dies (``PR_SET_PDEATHSIG``) and watches the socket pair:
  end of file means the parent is gone, however it ended. It then stops as for
  SIGTERM and exits for good after `ORPHAN_GRACE_S` at the latest. Analysis
  workers do the same towards their fork server (`camcal.core.parallel`); the fork
  server and the resource tracker end when their own parent's pipe closes.
* **Exit statuses say what happened** (``EXIT_*``; docs/operations.md).

A supervisor also tells systemd when it is ready (``sd_notify``, for a unit
of ``Type=notify``), when ``NOTIFY_SOCKET`` is set.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from camcal.core import procinfo

#: Stopped as asked (SIGINT, SIGTERM), or the work is done.
EXIT_OK = 0
#: Stopped by a failure while running (a part died, a thread failed); see the log.
EXIT_FAILED = 1
#: Wrong option or configuration: nothing was started.
EXIT_USAGE = 2
#: Could not start (a port in use, a part not healthy in time); everything started was stopped.
EXIT_NOT_STARTED = 3

#: Environment variable naming the inherited end of the supervisor's socket pair: ``FD,PARENT_PID``.
CHANNEL_ENV = "CAMCAL_SUPERVISOR_FD"
#: After its parent is gone, a child stops in order; it exits for good after this long at the latest.
ORPHAN_GRACE_S = 3.0

_PR_SET_PDEATHSIG = 1
_channel: socket.socket | None = None
_channel_lock = threading.Lock()


# ---------------------------------------------------------------- ports
class PortInUse(Exception):
    """A port a part of camcal needs is taken; the message says by whom and what to change."""

    def __init__(self, part: str, host: str, port: int, setting: str) -> None:
        holder = procinfo.describe_holder(port)
        leftover = " (a camcal process left running? `camcal doctor` lists them)"
        leftover = leftover if "camcal" in holder else ""
        by = f" by {holder}{leftover}" if holder else ""
        super().__init__(
            f"the {part} cannot listen on {host}:{port}: the port is in use{by}. "
            f"{'Stop that process' if holder else 'Free it'}, or choose another port with {setting}."
        )
        self.part, self.host, self.port, self.setting, self.holder = part, host, port, setting, holder


def tcp_endpoint(endpoint: str) -> tuple[str, int] | None:
    """``tcp://*:5555`` -> ``("0.0.0.0", 5555)``; None for another transport or a random port (``*``)."""
    if not endpoint.startswith("tcp://") or ":" not in endpoint[6:]:
        return None
    host, port = endpoint[6:].rsplit(":", 1)
    if not port.isdigit():
        return None
    host = host.strip("[]")
    return ("0.0.0.0" if host == "*" else host), int(port)


def bind_tcp(host: str, port: int, *, part: str, setting: str) -> socket.socket:
    """A TCP socket bound to ``host:port`` (not yet listening), as servers bind (``SO_REUSEADDR``).

    Raises `PortInUse` naming ``part`` and ``setting`` if the port is taken.
    """
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise PortInUse(part, host, port, setting) from None
        raise OSError(f"the {part} cannot listen on {host}:{port}: {exc.strerror} (set {setting})") from None
    return sock


def check_port(host: str, port: int, *, part: str, setting: str) -> None:
    """Raise `PortInUse` if ``host:port`` cannot be bound now (a free port is left free).

    A host this check cannot resolve (a ZeroMQ interface name such as ``eth0``) is left to the service.
    """
    try:
        bind_tcp(host, port, part=part, setting=setting).close()
    except PortInUse:
        raise
    except OSError:
        return


def check_endpoint(endpoint: str, *, part: str, setting: str) -> None:
    """`check_port` for a ZeroMQ endpoint such as ``tcp://*:5555`` (other transports pass)."""
    hp = tcp_endpoint(endpoint)
    if hp is not None:
        check_port(*hp, part=part, setting=setting)


# ---------------------------------------------------------------- parent death
def die_with_parent(sig: int = signal.SIGTERM) -> bool:
    """Ask Linux to send ``sig`` to this process when the thread that started it ends.

    True if set; False where ``prctl`` is not available (not Linux).
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def exit_when_gone(pid: int) -> None:
    """Leave this process (``os._exit``) as soon as process ``pid`` ends.

    For helpers that hold nothing worth saving and whose parent is not the
    process they serve: an analysis worker is forked by the pool's fork
    server, which lives as long as any worker does, so only the pool's owner
    going away can end them both.
    """

    def watch() -> None:
        try:
            handle = os.pidfd_open(pid)  # Linux >= 5.3: readable once the process has ended
        except ProcessLookupError:
            os._exit(EXIT_FAILED)
        except (AttributeError, OSError):
            handle = None
        if handle is not None:
            select.select([handle], [], [])
        else:
            while procinfo.alive(pid) if procinfo.PROC.is_dir() else _signalable(pid):
                time.sleep(0.5)
        os._exit(EXIT_FAILED)

    threading.Thread(target=watch, name=f"exit-with-{pid}", daemon=True).start()


def _signalable(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


# ---------------------------------------------------------------- child side
def attach() -> None:
    """In a child of a `Supervisor` (else nothing): tie this process's life to its parent.

    Called first by the ``camcal`` command line. The channel is taken out of
    the environment so that this process's own children do not attach to it.
    """
    global _channel
    raw = os.environ.pop(CHANNEL_ENV, None)
    if not raw:
        return
    fd_text, _, ppid_text = raw.partition(",")
    try:
        fd, ppid = int(fd_text), int(ppid_text)
        sock = socket.socket(fileno=fd)
    except (ValueError, OSError):
        return  # not ours to use: a stale variable in a shell
    sock.set_inheritable(False)
    die_with_parent(signal.SIGTERM)
    if os.getppid() != ppid:  # the parent died before this process could tie itself to it
        os._exit(EXIT_FAILED)
    _channel = sock
    threading.Thread(target=_watch_parent, args=(sock,), name="supervisor-watch", daemon=True).start()


def _watch_parent(sock: socket.socket) -> None:
    try:
        while sock.recv(4096):  # the supervisor sends nothing: end of file means it is gone
            pass
    except OSError:
        pass
    os.kill(os.getpid(), signal.SIGTERM)  # stop in order, as for a service manager's stop
    time.sleep(ORPHAN_GRACE_S)
    os._exit(EXIT_FAILED)  # still here: leave for good


def _report(message: dict[str, Any]) -> None:
    with _channel_lock:
        if _channel is None:
            return
        with contextlib.suppress(OSError):
            _channel.sendall(json.dumps(message, default=str).encode() + b"\n")


def notify_ready(status: str = "", **info: Any) -> None:
    """Tell the supervisor (and systemd) that this service is up; ``info`` goes to the supervisor."""
    _report({"ready": True, "pid": os.getpid(), **info})
    sd_notify("READY=1" + (f"\nSTATUS={status}" if status else ""))


def notify_error(message: str) -> None:
    """Tell the supervisor why this service could not start (before exiting)."""
    _report({"error": message, "pid": os.getpid()})


def sd_notify(state: str) -> bool:
    """Send ``state`` (e.g. ``READY=1``) to systemd's ``NOTIFY_SOCKET``; False if there is none."""
    address = os.environ.get("NOTIFY_SOCKET")
    if not address:
        return False
    if address.startswith("@"):
        address = "\0" + address[1:]
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as s:
            s.connect(address)
            s.sendall(state.encode())
        return True
    except OSError:
        return False


# ---------------------------------------------------------------- parent side
class ChildFailed(Exception):
    """A child did not start, or ended while it should have run; the message names it and its log."""


@dataclass(eq=False)
class Child:
    """A ``camcal`` command started by a `Supervisor`."""

    name: str
    proc: subprocess.Popen[bytes]
    log: Path
    channel: socket.socket
    reports: list[dict[str, Any]] = field(default_factory=list)
    _buffer: bytes = b""
    _closed: bool = False

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def read_reports(self, timeout_s: float = 0.0) -> list[dict[str, Any]]:
        """Reports that arrived within ``timeout_s`` (one JSON object a line)."""
        new: list[dict[str, Any]] = []
        if self._closed:  # the child's end is closed (it exited): nothing more will come
            time.sleep(max(0.0, timeout_s))
        elif select.select([self.channel], [], [], max(0.0, timeout_s))[0]:
            try:
                chunk = self.channel.recv(65536)
            except OSError:
                chunk = b""
            self._closed = not chunk
            self._buffer += chunk
            *lines, self._buffer = self._buffer.split(b"\n")
            for line in lines:
                with contextlib.suppress(ValueError):
                    new.append(json.loads(line))
        self.reports += new
        return new

    def log_tail(self, lines: int = 12) -> str:
        try:
            text = self.log.read_text(errors="replace")
        except OSError:
            return ""
        return "\n".join(text.rstrip().splitlines()[-lines:])

    def describe_exit(self) -> str:
        code = self.proc.returncode
        if code is None:
            return "running"
        return f"killed by {signal.Signals(-code).name}" if code < 0 else f"exited with status {code}"


class Supervisor:
    """Starts ``camcal`` commands as children tied to this process, waits for them, stops them in order.

    Children must be started from the thread that lives as long as they should
    (the main thread): the kernel's parent-death signal follows that thread.
    """

    def __init__(self) -> None:
        self.children: list[Child] = []

    def spawn(self, name: str, args: list[str], log: Path, env: dict[str, str] | None = None) -> Child:
        """Start ``camcal ARGS`` in its own session (a terminal's Ctrl-C reaches only this process,
        which stops the children in order), output appended to ``log``."""
        parent_end, child_end = socket.socketpair()
        env = dict(os.environ if env is None else env)
        env.pop("NOTIFY_SOCKET", None)  # systemd hears from the supervisor only
        env[CHANNEL_ENV] = f"{child_end.fileno()},{os.getpid()}"
        try:
            with log.open("ab") as out:
                proc = subprocess.Popen(
                    [sys.executable, "-c", "from camcal.cli import main; main()", *args],
                    stdin=subprocess.DEVNULL,
                    stdout=out,
                    stderr=out,
                    env=env,
                    pass_fds=(child_end.fileno(),),
                    start_new_session=True,
                )
        except BaseException:
            parent_end.close()
            raise
        finally:
            child_end.close()
        child = Child(name, proc, log, parent_end)
        self.children.append(child)
        return child

    def wait_ready(
        self, child: Child, timeout_s: float, stop: threading.Event | None = None
    ) -> dict[str, Any] | None:
        """The child's ready report; `ChildFailed` if it reports an error, exits, or is silent too long;
        None as soon as ``stop`` is set."""
        end = time.monotonic() + timeout_s
        while not (stop is not None and stop.is_set()):
            for report in child.read_reports(0.1):
                if report.get("error"):
                    raise ChildFailed(f"{child.name}: {report['error']}")
                if report.get("ready"):
                    return report
            if not child.alive():
                child.read_reports(0.0)
                errors = [r["error"] for r in child.reports if r.get("error")]
                why = errors[0] if errors else f"{child.describe_exit()} before it was ready"
                raise ChildFailed(f"{child.name}: {why}; its log {child.log}:\n{child.log_tail()}")
            if time.monotonic() > end:
                raise ChildFailed(
                    f"{child.name} did not report ready within {timeout_s:g} s; its log {child.log}:\n"
                    f"{child.log_tail()}"
                )
        return None

    def exited(self) -> list[Child]:
        """Children that have ended."""
        return [c for c in self.children if not c.alive()]

    def stop(self, stages: list[list[Child]] | None = None, timeout_s: float = 4.0) -> None:
        """SIGTERM each stage in turn (default: the last started first) and wait for it to end, each
        stage taking its share of ``timeout_s``; then kill whatever is left with its process group
        (its fork server, workers, resource tracker). Everything is gone half a second after
        ``timeout_s`` at the latest."""
        stages = stages if stages is not None else [[c] for c in reversed(self.children)]
        end = time.monotonic() + timeout_s
        for i, stage in enumerate(stages):
            for c in stage:
                if c.alive():
                    c.proc.send_signal(signal.SIGTERM)
            stage_end = time.monotonic() + (end - time.monotonic()) / (len(stages) - i)
            for c in stage:
                with contextlib.suppress(subprocess.TimeoutExpired):
                    c.proc.wait(max(0.0, stage_end - time.monotonic()))
        for c in self.children:
            if c.alive():
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(c.pid, signal.SIGKILL)
        # A child's helpers end on their own once it is gone (their pipes close); give them a moment.
        groups_end = max(end, time.monotonic()) + 0.5
        for c in self.children:
            with contextlib.suppress(subprocess.TimeoutExpired):
                c.proc.wait(max(0.05, groups_end - time.monotonic()))
            while procinfo.group(c.pid) and time.monotonic() < groups_end:
                time.sleep(0.02)
            if procinfo.group(c.pid):
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(c.pid, signal.SIGKILL)
            c.channel.close()
