"""Server fixtures: a client on the shared simulated dive (``dive_data``, tests/conftest.py)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.settings import ServerSettings

TOKEN = "op-secret-token-1"


@pytest.fixture(scope="session")
def client(dive_data) -> Iterator[TestClient]:
    """A read-mostly client on the simulated dive (do not change data through it)."""
    data, _ = dive_data
    app = create_app(ServerSettings(data_dir=data, events=None, operator_tokens={"deck": TOKEN}))
    with TestClient(app) as c:
        yield c
