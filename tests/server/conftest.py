"""Server fixtures: one data folder filled by a real simulated dive, shared by read-only tests."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.settings import ServerSettings
from tests.utils.dive_store import run_simulated_dive

TOKEN = "op-secret-token-1"


@pytest.fixture(scope="session")
def dive_data(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, object]]:
    root = tmp_path_factory.mktemp("dive")
    info = run_simulated_dive(root / "data")
    return root / "data", info


@pytest.fixture(scope="session")
def client(dive_data) -> Iterator[TestClient]:
    """A read-mostly client on the simulated dive (do not change data through it)."""
    data, _ = dive_data
    app = create_app(ServerSettings(data_dir=data, events=None, operator_tokens={"deck": TOKEN}))
    with TestClient(app) as c:
        yield c
