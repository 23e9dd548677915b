"""The live page when the ship server cannot reach its database: it says so (not "connection lost"),
with what to do, and comes back by itself. Its own ``camcal serve`` on PostgreSQL through a relay
that is cut before the page opens and restored while it is open."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from tests.browser.conftest import camcal_page
from tests.utils.pg import served_on_a_relayed_database

pytestmark = pytest.mark.browser


def test_the_live_page_says_the_database_is_down_and_recovers(
    browser: Any, tmp_path: Path, artifacts: Path, pg_template: tuple[str, str] | None
) -> None:
    with (
        served_on_a_relayed_database(tmp_path / "data", pg_template) as (base, proxy),
        camcal_page(browser, SimpleNamespace(base_url=base)) as page,
    ):
        proxy.cut()
        page.goto(f"{base}/")
        page.wait_for_function(
            "() => /database cannot be used/.test(document.querySelector('#banner').textContent)"
        )
        banner = page.locator("#banner")
        assert banner.is_visible() and "camcal doctor" in banner.inner_text()
        assert "lost" not in banner.inner_text().split(".")[0]  # not taken for a lost connection
        page.screenshot(path=str(artifacts / "live-database-down.png"))

        proxy.restore()  # the server asks again within 5 s: the snapshot comes, the banner goes
        page.wait_for_function(
            "() => document.querySelector('#conn').dataset.state === 'live'", timeout=30_000
        )
        assert "database" not in banner.inner_text()
