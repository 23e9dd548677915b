"""Session-wide fixtures."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.utils.sim import small_frame_set


@pytest.fixture(scope="session")
def trex_small_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One small simulated frame set, shared by read-only tests (do not modify it)."""
    out = tmp_path_factory.mktemp("sets") / "trex-small"
    small_frame_set(out)
    return out


@pytest.fixture(scope="session")
def dive_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    """A data folder filled by a real simulated dive (~45 s), shared by read-only tests.

    Streamed once per run, however many pytest-xdist workers ask for it
    (`tests.utils.dive_store.shared_simulated_dive`). Tests that write to a store copy it
    first (`tests.utils.dive_store.copy_data`).
    """
    from tests.utils.dive_store import shared_simulated_dive  # the live stack, imported only when needed

    return shared_simulated_dive(tmp_path_factory.getbasetemp())


@pytest.fixture(scope="session")
def pg_template() -> Iterator[tuple[str, str] | None]:
    """(server URL, name of a migrated template database), or None without ``CAMCAL_TEST_PG_URL``."""
    from tests.utils.pg import migrated_template, pg_admin_url  # the ship's stack: not in a module's install

    admin = pg_admin_url()
    if admin is None:
        yield None
        return
    with migrated_template(admin) as name:
        yield admin, name


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request: pytest.FixtureRequest, pg_template: tuple[str, str] | None) -> Iterator[str | None]:
    """The store's database: ``None`` (SQLite in the data folder) or a fresh PostgreSQL database."""
    from tests.utils.pg import SKIP_REASON, fresh_database

    if request.param == "sqlite":
        yield None
        return
    if pg_template is None:
        pytest.skip(SKIP_REASON)
    with fresh_database(*pg_template) as url:
        yield url


@pytest.fixture
def pg_url(pg_template: tuple[str, str] | None) -> Iterator[str]:
    """A fresh, migrated PostgreSQL database (skips without ``CAMCAL_TEST_PG_URL``)."""
    from tests.utils.pg import SKIP_REASON, fresh_database

    if pg_template is None:
        pytest.skip(SKIP_REASON)
    with fresh_database(*pg_template) as url:
        yield url


@pytest.fixture
def pg_empty_url() -> Iterator[str]:
    """A fresh, empty PostgreSQL database (skips without ``CAMCAL_TEST_PG_URL``)."""
    from tests.utils.pg import SKIP_REASON, fresh_database, pg_admin_url

    admin = pg_admin_url()
    if admin is None:
        pytest.skip(SKIP_REASON)
    with fresh_database(admin) as url:
        yield url


@pytest.fixture(scope="session")
def browser() -> Iterator[Any]:
    """One headless Chromium (Debian's, through Playwright) for the session: skips without either.

    Every test that needs a browser takes this fixture: Playwright's sync API cannot be started
    twice in one process while the first is running.
    """
    from tests.utils.system import CHROMIUM, CHROMIUM_ARGS

    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} is missing: install Debian's chromium (apt-get install -y chromium)")
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright (Python) is not installed")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="session")
def dask_runner() -> Iterator[object]:
    """A two-worker Dask `LocalCluster` (processes) shared by the re-analysis tests."""
    from ingest.runners import DaskRunner

    runner = DaskRunner(workers=2)
    yield runner
    runner.close()
