"""Reading stored data never fails on a value: every GET route over a store full of extreme rows.

Rows are written straight into every table (no ingest, no checks): infinities,
NaN where the database keeps it (PostgreSQL; SQLite turns NaN into NULL),
the largest doubles and integers, times in years 1 and 9999, the longest
strings, JSON holding NaN and Infinity. Then every GET route of the API is
called with every id: none may answer 5xx, and every JSON body must be
strict JSON.
"""

from __future__ import annotations

import gc
import itertools
import json
import re
from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import JSON, BigInteger, Boolean, Float, Integer, String, Text, insert

from camcal.core.events import finite_json
from server.app import create_app
from server.settings import ServerSettings
from storage.models import Base
from storage.store import Store

FLOATS = [
    float("inf"),
    float("-inf"),
    1e308,
    -1e308,
    float("nan"),
    0.0,
    -0.0,
    1.7e9,
    253402300799.0,
    -62135596800.0,
]
BIG_JSON = {"x": float("nan"), "y": [float("inf"), -1e308], "z": {"deep": [[[1]]]}, "n": 2**63 - 1}
N_ROWS = 4


def _value(col: Any, i: int, sqlite: bool) -> Any:
    t = col.type
    j = i + hash(col.name) % 7
    if isinstance(t, Float):
        v = FLOATS[j % len(FLOATS)]
        if v != v and sqlite and not col.nullable:  # SQLite stores NaN as NULL: not in a NOT NULL column
            return float("inf")
        return v
    if isinstance(t, Boolean):
        return bool(i % 2)
    if isinstance(t, BigInteger):
        return [2**63 - 1, -(2**63), 0, 1][j % 4]
    if isinstance(t, Integer):
        return [2**31 - 1, -(2**31), 0, 460][j % 4]
    if isinstance(t, JSON):
        v = [BIG_JSON, {}, [], {"pairs": [[None, float("inf")]]}][j % 4]
        return v if sqlite else finite_json(v)  # PostgreSQL's JSON type refuses NaN and Infinity
    if isinstance(t, String | Text):
        n = t.length or 300
        return ["", "." * n, ("<b>é\u202e" * n)[:n], f"s{i}"][j % 4]
    raise AssertionError(f"no extreme value for {col.table.name}.{col.name} ({t})")


def fill(store: Store) -> dict[str, list[Any]]:
    """Insert ``N_ROWS`` extreme rows in every table; returns the primary keys per table."""
    sqlite = store.engine.dialect.name == "sqlite"
    keys: dict[str, list[Any]] = {}
    with store.session() as s:
        for table in Base.metadata.sorted_tables:
            rows = []
            for i in range(N_ROWS):
                row = {}
                for col in table.columns:
                    if col.foreign_keys:
                        (fk,) = col.foreign_keys
                        parents = keys[fk.column.table.name]
                        row[col.name] = (
                            None if col.nullable and i == N_ROWS - 1 else parents[i % len(parents)]
                        )
                    elif col.primary_key and isinstance(col.type, Integer | BigInteger):
                        row[col.name] = i + 1
                    elif col.primary_key:
                        row[col.name] = ["A", "B", "x" * 64, f"c{i}"][i]
                    elif col.name in ("seq", "name", "key", "version") or (
                        table.name == "frames" and col.name == "boot"
                    ):
                        row[col.name] = (
                            i + 1 if not isinstance(col.type, String | Text) else f"{col.name}-{i}"
                        )
                    else:
                        row[col.name] = _value(col, i, sqlite)
                rows.append(row)
            s.execute(insert(table), rows)
            pk = next(iter(table.primary_key.columns)).name
            keys[table.name] = [r[pk] for r in rows]
    return keys


def get_paths(routes: list[Any], prefix: str = "") -> list[str]:
    """Every GET path of an app, through its included routers (the docs pages aside)."""
    out = []
    for r in routes:
        if hasattr(r, "original_router"):  # an included router
            out += get_paths(r.original_router.routes, prefix + r.original_router.prefix)
        elif "GET" in (getattr(r, "methods", None) or ()) and not r.path.startswith(("/docs", "/redoc")):
            out.append(prefix + r.path)
    return out


def strict_json(text: str) -> Any:
    def refuse(name: str) -> Any:
        raise ValueError(f"{name} in a JSON body")

    return json.loads(text, parse_constant=refuse)


def test_every_get_route_copes_with_any_stored_row(tmp_path: Path, db_url: str | None) -> None:
    store = Store.open(tmp_path / "data", db_url)
    keys = fill(store)
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=None), store=store)
    ids = {
        "dive_id": keys["dives"],
        "frame_id": keys["frames"],
        "module_id": keys["modules"],
        "command_id": keys["commands"],
        "calibration_id": keys["calibrations"],
        "name": ["swagger-ui.css", "not-an-asset.js"],  # /vendor/docs/{name}
    }
    failures = []
    calls = 0
    with TestClient(app, raise_server_exceptions=False) as client:
        for route_path in get_paths(app.routes):
            params = re.findall(r"{(\w+)}", route_path)
            for combo in itertools.product(*(ids[p] for p in params)):
                path = route_path
                for name, value in zip(params, combo, strict=True):
                    path = path.replace("{" + name + "}", str(value))
                res = client.get(path)
                calls += 1
                if res.status_code >= 500:
                    failures.append((path, res.status_code, res.text[:200]))
                elif res.headers.get("content-type", "").startswith("application/json"):
                    try:
                        strict_json(res.text)
                    except ValueError as exc:
                        failures.append((path, "not strict JSON", str(exc)))
    store.close()
    gc.collect()  # a connection left open anywhere above warns now, in this test, not in a later one
    assert calls > 40
    assert failures == [], "\n".join(map(str, failures))
