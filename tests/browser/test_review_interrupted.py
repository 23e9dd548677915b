"""A re-analysis cut short by a killed server, on the review page: it reads "interrupted" with what
to do, and an operator runs it again with one click. Its own ``camcal serve`` of a stored dive,
killed (SIGKILL) while re-analyses wait, then started again."""

from __future__ import annotations

import signal
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from tests.browser.conftest import camcal_page
from tests.utils.dive_store import copy_data
from tests.utils.runs import OPERATOR_ENV, TOKEN, start_three
from tests.utils.system import camcal_serve

pytestmark = pytest.mark.browser


def test_an_interrupted_reanalysis_says_so_and_runs_again(
    browser: Any, dive_data: tuple[Path, dict[str, object]], tmp_path: Path, artifacts: Path
) -> None:
    data = copy_data(dive_data[0], tmp_path / "data")
    with camcal_serve(data, env=OPERATOR_ENV) as (url, proc):
        start_three(url)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    with (
        camcal_serve(data, env=OPERATOR_ENV) as (url, _),
        camcal_page(browser, SimpleNamespace(base_url=url)) as page,
    ):
        page.goto(f"{url}/review#tab=reanalysis")
        stopped = "#runs-table tr:has(.run-status[data-status='interrupted'])"
        page.wait_for_selector(stopped)
        assert "start it again" in page.locator(stopped).first.inner_text()
        assert page.locator(f"{stopped} .run-again").count() == 0  # only an operator may start one
        page.click("#login")
        page.fill("#login-token", TOKEN)
        page.click("#login-submit")
        page.wait_for_selector(f"{stopped} .run-again")
        label = page.locator(stopped).first.locator("td").nth(2).inner_text()
        page.screenshot(path=str(artifacts / "review-interrupted.png"), full_page=True)
        page.locator(f"{stopped} .run-again").first.click()
        again = f"#runs-table tr:has-text('{label} (again)')"
        page.wait_for_selector(f"{again} .run-status[data-status='done']", timeout=90_000)
        cells = page.locator(again).locator("td").all_inner_texts()
        original = page.locator(stopped).first.locator("td").all_inner_texts()
        assert cells[6:] == original[6:], (cells, original)  # the same distances, ratios, linear range
        page.screenshot(path=str(artifacts / "review-run-again.png"), full_page=True)
