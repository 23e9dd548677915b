"""One configuration path: every command that opens the store finds it through the typed settings.

A ship sets ``CAMCAL_DATA_DIR`` and ``CAMCAL_DATABASE_URL`` (or a config file)
once; ``camcal import``, ``export``, ``report``, ``calibration``, ``fit --dive``
and ``reanalyze`` must then read that store, not an empty SQLite in the
working directory. Each command runs here with the environment only, in a
folder holding no store, on a dive whose database lives apart from its data
folder (so the URL is honoured, not only the folder).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from camcal.cli import app
from storage import queries
from storage.store import Store
from tests.utils.dive_store import copy_data


def run(args: list[str], env: dict[str, str] | None = None) -> tuple[int, str]:
    result = CliRunner().invoke(app, [str(a) for a in args], env=env)
    return result.exit_code, result.output


@pytest.fixture(autouse=True)
def no_camcal_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """Nothing configured but what a test sets, and a working directory without a store."""
    import os

    for var in [v for v in os.environ if v.startswith("CAMCAL_")]:
        monkeypatch.delenv(var)
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.chdir(tmp_path)


@pytest.fixture(scope="module")
def ship(
    dive_data: tuple[Path, dict[str, object]], tmp_path_factory: pytest.TempPathFactory
) -> dict[str, Any]:
    """A copy of the shared dive with its SQLite database moved out of the data folder."""
    root = tmp_path_factory.mktemp("config-path")
    data = copy_data(dive_data[0], root / "ship-data")
    db = root / "database" / "ship.db"
    db.parent.mkdir()
    for suffix in ("", "-wal", "-shm"):
        if (data / f"camcal.db{suffix}").exists():
            shutil.move(data / f"camcal.db{suffix}", db.parent / f"ship.db{suffix}")
    url = f"sqlite:///{db}"
    (name,) = dive_names(data, url)
    return {"data": data, "url": url, "dive": name, "root": root}


def dive_names(data: Path, url: str) -> list[str]:
    store = Store.open(data, url)
    try:
        return [d["name"] for d in store.call(queries.dives)]
    finally:
        store.close()


def env_of(ship: dict[str, Any]) -> dict[str, str]:
    return {"CAMCAL_DATA_DIR": str(ship["data"]), "CAMCAL_DATABASE_URL": ship["url"]}


def stored_calibrations(ship: dict[str, Any]) -> list[str]:
    store = Store.open(ship["data"], ship["url"])
    try:
        return [f"{c['name']}@{c['version']}" for c in store.call(queries.calibrations)]
    finally:
        store.close()


def test_without_the_environment_no_store_is_found(ship: dict[str, Any], tmp_path: Path) -> None:
    """The control: the same commands, nothing configured, find no store (and make none)."""
    for args in (
        ["report", ship["dive"], "--out", tmp_path / "r.html"],
        ["export", "--out", tmp_path / "out"],
        ["calibration", "list"],
        ["fit", "--dive", ship["dive"], "--quiet", "--no-store"],
        ["reanalyze", "--dive", ship["dive"]],
    ):
        code, out = run(args)
        assert code == 2 and "no camcal store here" in out, (args, out)
    assert not (tmp_path / "camcal-data").exists()


def test_every_store_command_reads_the_configured_store(ship: dict[str, Any], tmp_path: Path) -> None:
    env = env_of(ship)
    name = ship["dive"]

    code, out = run(["calibration", "add", "--name", "env-check"], env)
    assert code == 0, out
    assert "env-check@1" in stored_calibrations(ship)
    code, out = run(["calibration", "list"], env)
    assert code == 0 and "env-che" in out, out  # the table may cut the name to its column
    code, out = run(["calibration", "show", "env-check"], env)
    assert code == 0 and '"name": "env-check"' in out, out

    code, out = run(["export", "--out", tmp_path / "none", "--format", ""], env)
    assert code == 2 and "--format: name csv, parquet or both" in out, out  # it wrote run.json alone
    code, out = run(["export", "--out", tmp_path / "export", "--format", "csv"], env)
    assert code == 0 and f"dive {name}" in out, out
    assert (tmp_path / "export" / "frames.csv").read_text().count("\n") > 10

    code, out = run(["report", name, "--out", tmp_path / "report.html"], env)
    assert code == 0, out
    assert name in (tmp_path / "report.html").read_text(encoding="utf-8")

    # Found the dive and its frames (an empty store would have said "no camcal store" or "no dive").
    code, out = run(["fit", "--dive", name, "--depth-min", "9000", "--quiet", "--no-store"], env)
    assert code == 2 and "no analysed frame in the span" in out, out

    # Read the store's calibrations: the one added above is listed among those it knows.
    code, out = run(["reanalyze", "--dive", name, "--calibration", "nope"], env)
    assert code == 2 and "no calibration 'nope'" in out and "env-check@1" in out, out


def test_import_writes_into_the_configured_store(
    ship: dict[str, Any], trex_small_set: Path, tmp_path: Path
) -> None:
    code, out = run(["import", trex_small_set, "--dive", "from-card", "--no-analyse"], env_of(ship))
    assert code == 0, out
    assert "from-card" in dive_names(ship["data"], ship["url"])
    assert not (tmp_path / "camcal-data").exists()


def test_a_config_file_names_the_store(ship: dict[str, Any], tmp_path: Path) -> None:
    toml = tmp_path / "camcal.toml"
    toml.write_text(f'data_dir = "{ship["data"]}"\ndatabase_url = "{ship["url"]}"\n')
    code, out = run(["report", ship["dive"], "--out", tmp_path / "r.html"], {"CAMCAL_CONFIG": str(toml)})
    assert code == 0, out
    code, out = run(["calibration", "list"], {"CAMCAL_CONFIG": str(toml)})
    assert code == 0 and "calibrations" in out, out  # nothing configured: "no camcal store here", 2


def test_options_still_win_over_the_environment(ship: dict[str, Any], tmp_path: Path) -> None:
    env = env_of(ship)
    other = f"sqlite:///{tmp_path / 'other.db'}"
    code, out = run(["report", ship["dive"], "--db-url", other, "--out", tmp_path / "r.html"], env)
    assert code == 2 and f"no dive named '{ship['dive']}'" in out, out
    only_dir = {"CAMCAL_DATA_DIR": str(ship["data"])}
    code, out = run(["export", "--data", tmp_path / "elsewhere", "--out", tmp_path / "x"], only_dir)
    assert code == 2 and "elsewhere: no camcal store here" in out, out


def test_on_postgresql_the_environment_is_enough(pg_url: str, trex_small_set: Path, tmp_path: Path) -> None:
    """The ship of the bug report: PostgreSQL named in the environment, SQLite nowhere."""
    env = {"CAMCAL_DATA_DIR": str(tmp_path / "data"), "CAMCAL_DATABASE_URL": pg_url}
    code, out = run(["import", trex_small_set, "--dive", "pg-dive", "--no-analyse"], env)
    assert code == 0, out
    code, out = run(["calibration", "add", "--name", "pg-check"], env)
    assert code == 0, out
    code, out = run(["export", "--dive", "pg-dive", "--out", tmp_path / "export", "--format", "csv"], env)
    assert code == 0 and "dive pg-dive" in out, out
    assert not list((tmp_path / "data").glob("*.db"))
    assert dive_names(tmp_path / "data", pg_url) == ["pg-dive"]
    store = Store.open(tmp_path / "data", pg_url)
    try:
        assert [c["name"] for c in store.call(queries.calibrations)] == ["pg-check"]
    finally:
        store.close()
