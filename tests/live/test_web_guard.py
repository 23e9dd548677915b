"""The dashboard server's wall against a real ``camcal serve`` process, over real HTTP.

What a host on the ship's network can do without a token, and what it must
not: a flood of schedule previews (each up to 10,000 settings) is answered
in part with 503 and ``Retry-After`` while an operator's preview is still
computed; an ``X-Forwarded-For`` is believed from a configured proxy only,
so rotating it does not escape the wrong-token throttle; API answers carry
``Cache-Control: no-store``; a body that is not UTF-8 gets the documented
400; a boolean is not a number; and /redoc asks nothing of a CDN. The
figures (memory, CPU) are printed for the report; behaviour is asserted.

The server trusts 127.0.0.2 as its reverse proxy; requests sent from
other loopback addresses are other clients, each with its own wrong-token
count, so a throttle test holds off only the address it used.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from server.guard import CSP
from tests.browser.conftest import camcal_page
from tests.live.test_http_bounds import cpu_s, rss_kib
from tests.utils.dive_store import copy_data
from tests.utils.system import camcal_serve

TOKEN = "a-long-operator-token-for-the-guard-tests"
#: The reverse proxy the server is told to trust.
PROXY = "127.0.0.2"
#: An exposure grid and a gain grid of 64 values each (the most a schedule's grid may hold).
EXPOSURES_S = [round(0.0001 * 1.1**i, 6) for i in range(64)]
GAINS_DB = [round(0.1 * i, 1) for i in range(64)]


def big_schedule(name: str) -> dict[str, Any]:
    """A valid schedule of 3,536 settings at each of the three wavelengths (10,608 frames a pass)."""
    return {
        "name": name,
        "exposures_s": EXPOSURES_S[:50],
        "gains_db": GAINS_DB[:50],
        "blocks": [
            {"exposures_s": EXPOSURES_S[50:], "gains_db": GAINS_DB},
            {"exposures_s": EXPOSURES_S[:10], "gains_db": GAINS_DB[50:]},
        ],
    }


def client_from(address: str) -> httpx.Client:
    """An HTTP client whose connections come from ``address`` (any of 127.0.0.0/8 on Linux)."""
    return httpx.Client(transport=httpx.HTTPTransport(local_address=address), timeout=120)


@pytest.fixture(scope="module")
def served(dive_data, tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, int]]:
    data = copy_data(dive_data[0], tmp_path_factory.mktemp("guard") / "data")
    env = {
        "CAMCAL_OPERATOR_TOKENS": json.dumps({"deck": TOKEN}),
        "CAMCAL_HTTP_TRUSTED_PROXIES": json.dumps([PROXY]),
    }
    with camcal_serve(data, env=env) as (url, proc):
        yield url, proc.pid


def test_a_flood_of_previews_is_bounded_and_an_operator_still_gets_one(served) -> None:
    url, pid = served
    before_kib, before_cpu = rss_kib(pid), cpu_s(pid)
    answers: list[httpx.Response] = []
    first_busy = threading.Event()
    start = threading.Barrier(30)

    def anonymous(i: int) -> None:
        with client_from("127.0.0.1") as c:
            start.wait()
            r = c.post(f"{url}/api/schedules/preview", json={"schedule": big_schedule(f"flood-{i}")})
        answers.append(r)
        if r.status_code == 503:
            first_busy.set()

    threads = [threading.Thread(target=anonymous, args=(i,)) for i in range(30)]
    for t in threads:
        t.start()
    assert first_busy.wait(120), "30 previews at once and none refused: the previews are not bounded"
    # The anonymous slots are taken now: an operator's preview has slots of its own.
    with client_from("127.0.0.1") as c:
        mine = c.post(
            f"{url}/api/schedules/preview",
            json={"schedule": big_schedule("operator")},
            headers={"Authorization": f"Bearer {TOKEN}"},
        )
    for t in threads:
        t.join(120)
    grown_mib = (rss_kib(pid) - before_kib) / 1024
    codes = sorted(r.status_code for r in answers)
    print(
        f"30 previews of 10,608 frames at once without a token: {codes.count(200)} answered, "
        f"{codes.count(503)} refused (503); server CPU {cpu_s(pid) - before_cpu:.1f} s, "
        f"memory +{grown_mib:.0f} MiB; the operator's preview during the flood: {mine.status_code}"
    )
    assert mine.status_code == 200, mine.text[:300]
    assert len(mine.json()["predictions"]) >= 1 and mine.json()["n_frames"] == 10_608
    assert set(codes) <= {200, 503}, codes
    for r in answers:
        if r.status_code == 503:
            assert r.headers["retry-after"] == "1"
            assert "try again in a second" in r.json()["error"]["message"], r.text
            assert r.headers["cache-control"] == "no-store"
    assert codes.count(200) >= 1
    assert grown_mib < 60, f"the server's memory grew by {grown_mib:.0f} MiB"
    assert httpx.get(f"{url}/api/health", timeout=10).status_code == 200


def test_api_answers_are_never_cached(served) -> None:
    url, _ = served
    with client_from("127.0.0.1") as c:
        dive = c.get(f"{url}/api/dives").json()[0]["id"]
        auth = {"Authorization": f"Bearer {TOKEN}"}
        for r in (
            c.get(f"{url}/api/dives"),
            c.get(f"{url}/api/operator", headers=auth),
            c.get(f"{url}/api/dives/{dive}/timeline"),
            c.get(f"{url}/api/frames/999999999"),  # an error is JSON too
            c.get(f"{url}/openapi.json"),
            c.post(f"{url}/api/schedules/preview", json={"schedule": big_schedule("one")}),
        ):
            assert r.headers.get("cache-control") == "no-store", (r.request.url, r.headers)
            assert r.headers["content-security-policy"] == CSP
        assert c.get(f"{url}/api/operator", headers=auth).json()["operator"] == "deck"
        # What may be cached keeps its own header: the scripts, and a frame's immutable thumbnail.
        assert "no-store" not in c.get(f"{url}/vendor/plotly.min.js").headers["cache-control"]
        frame = c.get(f"{url}/api/frames?dive={dive}&limit=1").json()["items"][0]["id"]
        assert "immutable" in c.get(f"{url}/api/frames/{frame}/thumbnail").headers["cache-control"]


def test_a_body_that_is_not_utf8_gets_the_documented_400(served) -> None:
    url, _ = served
    latin1 = '{"schedule": {"name": "Überprüfung", "exposures_s": [0.1], "gains_db": [6]}}'.encode("latin-1")
    with client_from("127.0.0.1") as c:
        r = c.post(
            f"{url}/api/schedules/preview", content=latin1, headers={"Content-Type": "application/json"}
        )
        assert r.status_code == 400, r.text
        error = r.json()["error"]
        assert error["code"] == "not_utf8" and "UTF-8" in error["message"], error
        # The same bytes in UTF-8 are fine.
        good = latin1.decode("latin-1").encode()
        ok = c.post(
            f"{url}/api/schedules/preview", content=good, headers={"Content-Type": "application/json"}
        )
        assert ok.status_code == 200, ok.text
        spec = c.get(f"{url}/openapi.json").json()
    answers = spec["paths"]["/api/schedules/preview"]["post"]["responses"]
    assert "400" in answers and "UTF-8" in answers["400"]["description"]
    assert "503" in answers and "previews" in answers["503"]["description"]
    # Every route with a body lists it.
    for path, ops in spec["paths"].items():
        for method, op in ops.items():
            if "requestBody" in op:
                assert "400" in op["responses"], (method, path)


def test_a_boolean_is_not_a_number(served) -> None:
    url, _ = served
    auth = {"Authorization": f"Bearer {TOKEN}"}
    with client_from("127.0.0.1") as c:
        before = len(c.get(f"{url}/api/calibrations").json())
        r = c.post(
            f"{url}/api/calibrations",
            json={"name": "bool-test", "setup": {}, "valid_to_unix_s": False},
            headers=auth,
        )
        assert r.status_code == 422, r.text
        assert r.json()["error"]["message"].startswith("valid_to_unix_s: Input should be a valid number")
        r = c.post(
            f"{url}/api/calibrations",
            json={"name": "bool-test", "setup": {"cameras": {"A": {"distance_m": True}}}},
            headers=auth,
        )
        assert r.status_code == 422 and "distance_m" in r.json()["error"]["message"], r.text
        assert len(c.get(f"{url}/api/calibrations").json()) == before, "a refused calibration was stored"
        for bad in ({"repeats": True}, {"exposures_s": [True]}, {"version": 2.0}, {"pause_s": "5"}):
            schedule = {"exposures_s": [0.1], "gains_db": [6], **bad}
            r = c.post(f"{url}/api/schedules/preview", json={"schedule": schedule})
            assert r.status_code == 422, (bad, r.text)
            assert next(iter(bad)) in r.json()["error"]["message"], r.text
        dive = c.get(f"{url}/api/dives").json()[0]["id"]
        for bad in ({"linear_range": [False, 200]}, {"calibration_id": True}):
            r = c.post(f"{url}/api/dives/{dive}/reanalyses", json=bad, headers=auth)
            assert r.status_code == 422, (bad, r.text)
        # Integers stay numbers: 6 for a gain in dB is 6.0.
        ok = c.post(f"{url}/api/schedules/preview", json={"schedule": {"exposures_s": [1], "gains_db": [6]}})
        assert ok.status_code == 200, ok.text


def wrong_tokens(c: httpx.Client, url: str, n: int, forwarded: Any) -> list[int]:
    """``n`` calibrations sent with a wrong token; ``forwarded(i)`` is the i-th X-Forwarded-For."""
    codes = []
    for i in range(n):
        r = c.post(
            f"{url}/api/calibrations",
            json={"name": "x", "setup": {}},
            headers={"Authorization": "Bearer wrong-token-0123", "X-Forwarded-For": forwarded(i)},
        )
        codes.append(r.status_code)
    return codes


def test_the_configured_proxy_names_the_client(served) -> None:
    url, _ = served
    with client_from(PROXY) as c:
        codes = wrong_tokens(c, url, 12, lambda i: "10.1.0.1")
        assert codes[:10] == [403] * 10 and set(codes[10:]) == {429}, codes
        # Another client behind the same proxy is not held off ...
        assert wrong_tokens(c, url, 1, lambda i: "10.1.0.2") == [403]
        # ... and the held-off one cannot escape by putting another address in front of its own:
        # the proxy appends the address it saw, the last one no trusted proxy added is the client.
        assert wrong_tokens(c, url, 1, lambda i: "10.7.7.7, 10.1.0.1") == [429]
        # Through the proxy with the right token, from a client that is not held off.
        r = c.get(
            f"{url}/api/operator",
            headers={"Authorization": f"Bearer {TOKEN}", "X-Forwarded-For": "10.1.0.3"},
        )
        assert r.status_code == 200 and r.json()["operator"] == "deck", r.text


def test_redoc_asks_nothing_of_a_cdn(served, browser: Any, tmp_path: Path) -> None:
    url, _ = served
    policy: list[str] = []
    with camcal_page(browser, url) as pg:  # a request outside the server fails the test
        pg.on("console", lambda m: policy.append(m.text) if "Content Security Policy" in m.text else None)
        pg.goto(f"{url}/redoc")
        pg.wait_for_selector("[data-section-id]", timeout=30_000)
        pg.wait_for_timeout(500)  # the menu's footer renders after the operations
        assert pg.get_by_text("API docs by Redocly").count() == 1
        pg.screenshot(path=str(tmp_path / "redoc.png"))
    assert policy == [], policy


def test_a_rotating_x_forwarded_for_does_not_escape_the_token_throttle(served) -> None:
    url, _ = served
    # From 127.0.0.1, the address uvicorn itself believed X-Forwarded-For from: the ship's computer
    # is no proxy of this server, so its header means nothing. (Last in this file: 127.0.0.1 is
    # held off for a minute after it.)
    with client_from("127.0.0.1") as c:
        codes = wrong_tokens(c, url, 30, lambda i: f"10.9.{i}.1")
    print(f"30 wrong tokens from one host with a new X-Forwarded-For each: {codes}")
    assert codes[:10] == [403] * 10 and set(codes[10:]) == {429}, codes
