"""Re-analyses started on a real ``camcal serve``, and the runs as its SQLite file holds them."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import httpx

TOKEN = "a-long-operator-token-for-tests"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
#: The environment of a ``camcal serve`` that takes `TOKEN` from an operator named "deck".
OPERATOR_ENV = {"CAMCAL_OPERATOR_TOKENS": json.dumps({"deck": TOKEN})}


def runs_in_file(data: Path) -> dict[int, tuple[str, str]]:
    """The re-analyses as the database file holds them (kind, status), read without any server."""
    with sqlite3.connect(data / "camcal.db") as db:
        rows = db.execute("SELECT id, kind, status FROM analysis_runs WHERE kind != 'live'").fetchall()
    return {r[0]: (r[1], r[2]) for r in rows}


def start_three(url: str) -> tuple[int, list[int]]:
    """Three re-analyses of the first dive asked for at once (each with its own linear range, so
    each analyses every frame again: ~1 s or more apiece); returns the dive and the run ids."""
    dive = httpx.get(f"{url}/api/dives").json()[0]["id"]
    ids = []
    for i in range(3):
        body = {"label": f"stop {i}", "linear_range": [15, 230 - i]}
        r = httpx.post(f"{url}/api/dives/{dive}/reanalyses", json=body, headers=AUTH, timeout=30)
        assert r.status_code == 202, r.text
        ids.append(r.json()["id"])
    return dive, ids
