"""The OpenAPI schema exercised by schemathesis: no generated input makes the server fail (5xx).

Schemathesis generates requests from the app's own OpenAPI document for every
operation; they run in-process against the app on a store filled by a real
simulated dive. (Its pytest plugin does not work with pytest 9, so the
operations are driven here with Hypothesis directly.)
"""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from starlette.testclient import TestClient

from server.app import create_app
from server.settings import ServerSettings
from tests.server.conftest import TOKEN


@pytest.fixture(scope="module")
def api_app(dive_data):
    data, _ = dive_data
    app = create_app(ServerSettings(data_dir=data, events=None, operator_tokens={"deck": TOKEN}))
    with TestClient(app):  # the lifespan runs while the schema is exercised
        yield app


def test_no_generated_input_makes_the_server_fail(api_app) -> None:
    schema = schemathesis.openapi.from_asgi("/openapi.json", api_app)
    operations = [r.ok() for r in schema.get_all_operations()]
    assert len(operations) >= 15
    failures: list[str] = []
    for op in operations:

        @given(case=op.as_strategy())
        @settings(max_examples=15, deadline=None, database=None, suppress_health_check=list(HealthCheck))
        def check(case) -> None:
            if case.method.upper() != "GET":  # operator actions are tried without a valid token
                case.headers = {**(case.headers or {}), "Authorization": "Bearer not-a-valid-token"}
            response = case.call()
            if response.status_code >= 500:
                failures.append(
                    f"{case.method} {case.formatted_path} -> {response.status_code}: {response.text[:200]}"
                )
            elif response.status_code >= 400 and "json" in response.headers.get("content-type", ""):
                assert set(response.json()) == {"error"}, response.text[:200]

        check()
    assert not failures, "\n".join(failures[:10])
