"""How routes are declared: every JSON answer has a model, and no route reaches the store on the loop."""

from __future__ import annotations

import inspect
from typing import Any

from fastapi.responses import JSONResponse

from server.app import create_app
from server.deps import get_store
from server.openapi import api_routes
from server.settings import ServerSettings


def _routes(tmp_path: Any) -> list[tuple[Any, str]]:
    app = create_app(ServerSettings(data_dir=tmp_path / "data", events=None))
    return [(r, path) for r, path in api_routes(app.routes) if r.include_in_schema]


def _uses_store(dependant: Any) -> bool:
    return any(d.call is get_store or _uses_store(d) for d in dependant.dependencies)


def test_every_json_route_declares_its_response_model(tmp_path) -> None:
    routes = _routes(tmp_path)
    assert len(routes) >= 40
    untyped = []
    for route, path in routes:
        cls = getattr(route.response_class, "value", route.response_class)
        if route.response_model is None and issubclass(cls, JSONResponse):
            untyped.append(f"{sorted(route.methods)} {path}")
    assert not untyped, untyped


def test_no_route_that_reaches_the_store_runs_on_the_event_loop(tmp_path) -> None:
    """A route using the store is a plain ``def`` (FastAPI runs it in its thread pool)."""
    on_loop = [
        path
        for route, path in _routes(tmp_path)
        if _uses_store(route.dependant) and inspect.iscoroutinefunction(route.endpoint)
    ]
    assert not on_loop, on_loop
    assert any(_uses_store(route.dependant) for route, _ in _routes(tmp_path))
