"""Processes of the real system for the dashboard benchmarks: the CLI, a spawned service, its HTTP up."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.utils.system import wait_until  # noqa: E402


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else math.nan


def cli(*args: str) -> list[str]:
    return [sys.executable, "-c", "from camcal.cli import main; main()", *args]


def spawn(args: list[str], log: Path) -> subprocess.Popen[bytes]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CAMCAL_")}
    env["PYTHONPATH"] = str(REPO)
    env["CAMCAL_HTTP_MAX_CONNECTIONS_PER_CLIENT"] = "64"  # the simulated browsers share one address
    with log.open("ab") as fh:
        return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT, env=env, cwd=log.parent)


def wait_http(url: str, timeout_s: float = 60) -> None:
    def up() -> bool:
        try:
            return httpx.get(url, timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    wait_until(up, timeout_s, url, every_s=0.2)
