"""The OpenAPI schema exercised by schemathesis, with and without a valid token.

Schemathesis generates requests from the app's own OpenAPI document for
every operation; they run in-process against the app. Every response must
be no server error (no 5xx), have a status code the document lists for
its operation (no undocumented answer) and a body that matches the
response model the document gives for it. Without a token the operator
actions are tried with a wrong one (on the shared simulated dive, which
nothing may change); with the token they really run, on a copy of it.
(Its pytest plugin does not work with pytest 9, so the operations are
driven here with Hypothesis directly.)
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from schemathesis.checks import not_a_server_error, response_schema_conformance, status_code_conformance
from starlette.testclient import TestClient

from server.app import create_app
from server.settings import ServerSettings
from tests.server.conftest import TOKEN
from tests.utils.dive_store import copy_data

#: Generated examples per operation.
EXAMPLES = 15


def api_app(data: Path) -> Iterator[object]:
    # Wrong tokens are part of the test: do not let the rate limit answer for the server.
    app = create_app(
        ServerSettings(data_dir=data, events=None, operator_tokens={"deck": TOKEN}, token_failures=10**9)
    )
    with TestClient(app):  # the lifespan runs while the schema is exercised
        yield app


@pytest.fixture(scope="module")
def shared_app(dive_data) -> Iterator[object]:
    yield from api_app(dive_data[0])


@pytest.fixture(scope="module")
def own_app(dive_data, tmp_path_factory: pytest.TempPathFactory) -> Iterator[object]:
    yield from api_app(copy_data(dive_data[0], tmp_path_factory.mktemp("schemathesis") / "data"))


def exercise(app: object, token: str | None) -> tuple[list[str], Counter[int]]:
    schema = schemathesis.openapi.from_asgi("/openapi.json", app)
    operations = [r.ok() for r in schema.get_all_operations()]
    assert len(operations) >= 15
    failures: list[str] = []
    codes: Counter[int] = Counter()
    for op in operations:

        @given(case=op.as_strategy())
        @settings(
            max_examples=EXAMPLES, deadline=None, database=None, suppress_health_check=list(HealthCheck)
        )
        def check(case) -> None:
            if token is not None:
                case.headers = {**(case.headers or {}), "Authorization": f"Bearer {token}"}
            elif case.method.upper() != "GET":  # operator actions are tried without a valid token
                case.headers = {**(case.headers or {}), "Authorization": "Bearer not-a-valid-token"}
            response = case.call()
            codes[response.status_code] += 1
            try:
                case.validate_response(
                    response,
                    checks=[not_a_server_error, status_code_conformance, response_schema_conformance],
                )
            except Exception as exc:  # schemathesis raises a group of failures: keep its first line
                first = str(exc).splitlines()[0]
                failures.append(f"{case.method} {case.formatted_path} -> {response.status_code}: {first}")
            if response.status_code >= 400 and "json" in response.headers.get("content-type", ""):
                assert set(response.json()) == {"error"}, response.text[:200]

        check()
    return failures, codes


def test_no_generated_input_without_a_valid_token_fails_or_gets_an_undocumented_answer(shared_app) -> None:
    failures, codes = exercise(shared_app, None)
    print(f"schemathesis without a token: {sum(codes.values())} requests, {dict(sorted(codes.items()))}")
    assert not failures, "\n".join(failures[:10])
    assert not [c for c in codes if c >= 500]


def test_no_generated_input_with_the_token_fails_or_gets_an_undocumented_answer(own_app) -> None:
    failures, codes = exercise(own_app, TOKEN)
    print(f"schemathesis with the token: {sum(codes.values())} requests, {dict(sorted(codes.items()))}")
    assert not failures, "\n".join(failures[:10])
    assert not [c for c in codes if c >= 500]
    assert codes[200] + codes[201] + codes[202] > 0, "the token opened no door"
