"""A review-only `camcal serve` of a finished dive: the pages are honest about what is not live.

Its own `camcal serve --events none` over a copy of the shared simulated dive, both modules signed
off (as they are once back on deck). The top bar said a green "OK" there, beside "ingest down", with
both modules' data hours old; the χ² tab logged a 404 in the console when the dive had no fit; the
audit log's "what happened" was the page's own and in no CSV.
"""

from __future__ import annotations

import csv
import io
import uuid
from datetime import UTC, datetime
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from storage.store import Store
from tests.browser.conftest import camcal_page
from tests.utils.dive_store import copy_data
from tests.utils.system import camcal_serve

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def served(dive_data, tmp_path_factory: pytest.TempPathFactory) -> Any:
    data = copy_data(dive_data[0], tmp_path_factory.mktemp("review-only") / "data")
    store = Store.open(data, None)
    try:
        for m in ("A", "B"):  # what the ingest records when a module says bye
            store.raise_alarm(f"signed_off:{m}", "signed_off", "INFO", f"module {m} signed off", m)
        cid = uuid.uuid4().hex
        store.audit("ops", "command.pause", "module:A", {"command_id": cid})
        store.audit(
            "module:A",
            "command.rejected",
            "module:A",
            {"command_id": cid, "action": "pause", "reason": "not running"},
        )
    finally:
        store.close()
    with camcal_serve(data) as (url, _):
        yield SimpleNamespace(base_url=url, url=lambda p: f"{url}{p}", cid=cid)


def test_the_top_bar_is_the_worst_of_its_parts_with_the_reason(
    browser: Any, served: Any, artifacts: Path
) -> None:
    with camcal_page(browser, served) as page:
        for width in (1440, 820, 390):
            page.set_viewport_size({"width": width, "height": 900})
            page.goto(served.url("/"))
            page.wait_for_selector("#module-A")
            page.wait_for_function(
                "() => document.querySelector('#ingest-state').textContent.includes('down')"
            )
            overall = page.locator("#overall")
            assert overall.inner_text() != "OK", "a green OK while the ingest is down and the modules are off"
            assert overall.inner_text() == "INVALID"
            why = page.locator("#overall-why")
            assert why.is_visible() and "ingest down" in why.inner_text(), why.inner_text()
            # the other parts are named in its tooltip: the modules signed off
            assert "LRM-A, LRM-B signed off (INFO)" in overall.get_attribute("title"), overall.get_attribute(
                "title"
            )
            page.screenshot(path=artifacts / f"review-only-live-{width}.png")


def test_a_dive_without_a_fit_asks_for_none_and_the_audit_says_what_its_csv_says(
    browser: Any, served: Any, artifacts: Path
) -> None:
    with camcal_page(browser, served) as page:
        failed: list[str] = []
        page.on("response", lambda r: failed.append(f"{r.status} {r.url}") if r.status >= 400 else None)
        page.goto(served.url("/review#tab=attenuation"))
        page.wait_for_selector("#chisq-fit:has-text('No χ² fit kept for this run yet')")
        page.wait_for_timeout(500)
        assert not failed, failed

        page.click(".tabs [data-tab=audit]")
        row = page.locator(f"#audit-table tr:has-text('command.rejected'):has-text('#{served.cid[:8]}')")
        row.wait_for()
        shown = row.locator("td.what").inner_text()
        assert shown == f"LRM-A rejected the pause command #{served.cid[:8]}: not running"
        text = page.evaluate("() => fetch('/api/audit/export').then(r => r.text())")
        rows = list(csv.DictReader(io.StringIO(text)))
        mine = next(r for r in rows if r["action"] == "command.rejected" and served.cid in r["details"])
        assert mine["what"] == shown  # the CSV says what the page says
        at = datetime.fromtimestamp(float(mine["t_unix_s"]), UTC).isoformat(timespec="milliseconds")
        assert mine["t_utc"] == at.replace("+00:00", "Z"), mine
        page.screenshot(path=artifacts / "review-only-audit.png", full_page=True)
        assert not failed, failed
