"""Browser tests: the real system (``camcal up``) and headless Chromium driven by Playwright.

One short simulated dive is shared by the browser tests (speed 20,
fast winch): frames and λ_att points arrive within ~30 s. Pages may only
reach the camcal server: any other request is refused and fails the test
(no CDN, no web fonts, nothing from the internet). Screenshots go to
``test-artifacts/`` at the top of the repository.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest

from tests.utils.pace import Pace
from tests.utils.system import REPO, SHORT_DIVE, System, camcal_up, wait_until

#: The browser tests' shared dive: `SHORT_DIVE` with an hour on station.
BROWSER_DIVE = {**SHORT_DIVE, "--station-s": "3600"}


@pytest.fixture(scope="package")
def system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    """``camcal up`` for the browser tests; stopped after them (its simulated dive loads both cores).

    The short dive with an hour on station (3 min at speed 20): the modules stay linked and keep
    adding λ_att visits for as long as the package's tests run, whatever their order and pace."""
    with camcal_up(tmp_path_factory.mktemp("browser") / "data", dive=BROWSER_DIVE) as s:
        yield s


@pytest.fixture(scope="session")
def artifacts() -> Path:
    out = REPO / "test-artifacts"
    out.mkdir(exist_ok=True)
    return out


@contextlib.contextmanager
def camcal_page(browser: Any, system: System | str) -> Iterator[Any]:
    """A fresh page that can reach only the camcal server (a `System` or a base URL); page errors
    fail the test."""
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    context.set_default_timeout(Pace().bound(20) * 1000)  # 20 s of an idle machine (`tests.utils.pace`)
    host = urlsplit(system if isinstance(system, str) else system.base_url).netloc
    foreign: list[str] = []
    errors: list[str] = []

    def only_camcal(route: Any) -> None:
        url = route.request.url
        if url.startswith(("data:", "blob:")) or urlsplit(url).netloc == host:
            route.continue_()
        else:
            foreign.append(url)
            route.abort()

    context.route("**/*", only_camcal)
    pg = context.new_page()
    pg.on("pageerror", lambda e: errors.append(str(e)))
    yield pg
    context.close()
    assert not foreign, f"the page asked for something outside the camcal server: {foreign}"
    assert not errors, f"JavaScript errors on the page: {errors}"


@pytest.fixture
def page(browser: Any, system: System) -> Iterator[Any]:
    """A fresh page of the session's system (see `camcal_page`)."""
    with camcal_page(browser, system) as pg:
        yield pg


@pytest.fixture(scope="package")
def dive_with_data(system: System) -> dict[str, Any]:
    """The dive once it has analysed frames of both modules, λ_att and linearity fits (waits for them)."""

    def ready() -> dict[str, Any] | None:
        try:
            dives = httpx.get(system.url("/api/dives"), timeout=5).json()
            if not dives:
                return None
            dive = dives[0]
            ok = httpx.get(system.url(f"/api/frames?dive={dive['id']}&status=ok&limit=1"), timeout=5).json()
            att = httpx.get(system.url(f"/api/attenuation?dive={dive['id']}"), timeout=5).json()
            lin = httpx.get(system.url(f"/api/linearity?dive={dive['id']}"), timeout=5).json()
        except httpx.HTTPError:
            return None
        modules = {c["module"] for c in lin["checks"]}
        if ok["total"] >= 30 and any(att["series"].values()) and len(modules) >= 2:
            return dive
        return None

    return wait_until(ready, 120, "analysed frames, a λ_att point and linearity fits of both modules")


#: The order of the browser files: those with a system of their own first, then the shared
#: system's tests that need no data (its dive meanwhile reaches the test stop), then the rest.
FILE_ORDER = ("test_cold_start", "test_database_down", "test_control", "test_security", "test_file_routes")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Every browser test runs after the rest in ``make test`` (marked solo: the shared system's
    simulated dive loads the cores; only the paced dive and station run beside them), in
    `FILE_ORDER`, then the other files in their own order."""
    here = Path(__file__).parent
    slots = [i for i, item in enumerate(items) if here in item.path.parents]
    ours = [items[i] for i in slots]

    def rank(item: pytest.Item) -> int:
        return FILE_ORDER.index(item.path.stem) if item.path.stem in FILE_ORDER else len(FILE_ORDER)

    for i, item in zip(slots, sorted(ours, key=rank), strict=True):
        item.add_marker(pytest.mark.solo)
        items[i] = item
