"""What a running camcal service listens on, told in its data folder: ``<data>/run/<service>-<pid>.json``.

``camcal up``, ``camcal ingest`` and ``camcal serve`` each write one when they
have bound their ports and remove it when they end. A service started with
options (``camcal up --port 8123 --ingest-port 5565``) has settings no
environment variable repeats: ``camcal doctor`` reads them here, so that it
checks the system that runs, not the defaults. A file whose process is gone
(killed with SIGKILL) or whose pid now belongs to another process is ignored
(and removed when it can be).
"""

from __future__ import annotations

import contextlib
import json
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from camcal.core import procinfo

RUN_DIR = "run"
#: A process's start time (from /proc) may differ from the one written by this much and be the same.
_START_SLACK_S = 2.0


@dataclass(frozen=True)
class RunningService:
    """One service's run file, its process alive."""

    service: str
    pid: int
    started_unix_s: float
    settings: dict[str, Any]
    installation: str
    path: Path


def _started(pid: int) -> float | None:
    p = procinfo.process(pid, procinfo.boot_time_unix_s())
    return p.started_unix_s if p is not None else None


def _runs(pid: int, started_unix_s: float) -> bool:
    """True while ``pid`` runs and is the process that wrote the file (not a later one given its pid)."""
    if not procinfo.PROC.is_dir():  # no /proc (not Linux): alive is all that can be told
        try:
            os.kill(pid, 0)
        except PermissionError:
            return True
        except OSError:
            return False
        return True
    now_started = _started(pid)
    return now_started is not None and abs(now_started - started_unix_s) <= _START_SLACK_S


def write(data_dir: Path, service: str, settings: dict[str, Any]) -> Path | None:
    """Write this process's run file (whole, by a rename); None if the folder cannot take it (a
    read-only data folder: the service runs anyway, and doctor falls back to the settings)."""
    folder = Path(data_dir) / RUN_DIR
    path = folder / f"{service}-{os.getpid()}.json"
    doc = {
        "service": service,
        "pid": os.getpid(),
        "started_unix_s": _started(os.getpid()) or time.time(),
        "written_unix_s": time.time(),
        "data_dir": str(Path(data_dir).resolve()),
        "installation": sys.prefix,
        "settings": settings,
    }
    try:
        folder.mkdir(parents=True, exist_ok=True)
        for old in running(data_dir, gone=True):  # of a service killed before it could remove its own
            remove(old.path)
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")
        tmp.replace(path)
    except OSError:
        return None
    return path


def remove(path: Path | None) -> None:
    if path is not None:
        with contextlib.suppress(OSError):
            path.unlink()


def running(data_dir: Path, *, gone: bool = False) -> list[RunningService]:
    """The services whose run files are in ``data_dir`` and whose processes still run, oldest first
    (``gone``: those whose processes are gone instead). Reading changes nothing."""
    out = []
    for path in sorted((Path(data_dir) / RUN_DIR).glob("*.json")):
        try:
            doc = json.loads(path.read_text(encoding="utf-8"))
            pid, started = int(doc["pid"]), float(doc["started_unix_s"])
            service, settings = str(doc["service"]), dict(doc.get("settings") or {})
        except (OSError, ValueError, KeyError, TypeError):
            continue
        if _runs(pid, started) == gone:
            continue
        out.append(RunningService(service, pid, started, settings, str(doc.get("installation", "")), path))
    return sorted(out, key=lambda r: r.started_unix_s)
