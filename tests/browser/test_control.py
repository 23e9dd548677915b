"""Schedule control in a real browser against the real system: edit, preview, confirm, follow, audit.

The tests of this file run on a system of their own (module A's schedule is
changed here; the session's shared dive must not see that). Its modules stay
at the first test stop for the whole file, so they keep taking frames.
"""

from __future__ import annotations

import csv
import io
import os
import signal
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from camcal.core.schedule import linearity_scan, trex_subsampled
from storage.store import Store
from tests.browser.conftest import camcal_page
from tests.utils.system import SHORT_DIVE, System, camcal_up, module_pid, wait_until

pytestmark = pytest.mark.browser

STEPS = ["pending", "sent", "accepted", "in_progress", "done"]
# Records every state the tracker shows for each command. Several states may be set within one task
# (the module's answers arrive together); each mutation record keeps the value before it, so the
# sequence is replayed from them. The page sets data-state, then data-command-id.
WATCH_TRACKER = """() => {
  window.trackerStates = [];
  const t = document.querySelector('#tracker');
  const ID = 'data-command-id';
  let id = t.dataset.commandId, state = t.dataset.state;
  const push = () => { const l = window.trackerStates; const last = l[l.length - 1];
                       if (state && !(last && last[0] === id && last[1] === state)) l.push([id, state]); };
  window.trackerObserver?.disconnect();  // one observer per page, however often this runs
  window.trackerObserver = new MutationObserver((records) => {
    const after = (i, name, now) => {
      for (const q of records.slice(i + 1)) if (q.attributeName === name) return q.oldValue;
      return now;
    };
    const finalId = t.dataset.commandId, finalState = t.dataset.state;
    for (let i = 0; i < records.length; i++) {
      if (records[i].attributeName === ID) { id = after(i, ID, finalId); continue; }
      state = after(i, 'data-state', finalState);
      if (records[i + 1]?.attributeName === ID) { id = after(i + 1, ID, finalId); i++; }
      push();
    }
  });
  const what = { attributes: true, attributeOldValue: true, attributeFilter: ['data-state', ID] };
  window.trackerObserver.observe(t, what);
}"""


@pytest.fixture(scope="module")
def control_system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    dive = {**SHORT_DIVE, "--winch-m-per-s": "20", "--test-stop-s": "3000", "--deck-s": "5"}
    with camcal_up(tmp_path_factory.mktemp("control") / "data", dive=dive) as s:
        yield s


def api(system: System, path: str) -> Any:
    r = httpx.get(system.url(path), timeout=10)
    r.raise_for_status()
    return r.json()


def commands(system: System, module: str = "A") -> list[dict[str, Any]]:
    return api(system, f"/api/modules/{module}/commands")


def login(page: Any, system: System) -> None:
    page.click("#login")
    page.fill("#login-token", system.token)
    page.click("#login-submit")
    page.wait_for_selector(f"#operator-name:has-text('{system.operator}')")
    hide_toast(page)


def open_control(page: Any, system: System) -> None:
    page.goto(system.url("/control#module=A"))
    page.wait_for_selector("#module-tabs [data-module='A'][aria-selected='true']")
    page.wait_for_selector("#current-schedule:has-text(' v')", timeout=30_000)


def hide_toast(page: Any) -> None:
    page.evaluate("document.getElementById('toast')?.setAttribute('hidden', '')")


def test_read_only_browser_sees_the_schedule_but_cannot_send(
    browser: Any, control_system: System, artifacts: Path
) -> None:
    with camcal_page(browser, control_system) as page:
        open_control(page, control_system)
        assert page.inner_text("#current-schedule") == "trex-subsampled v1"
        assert page.locator("#readonly-note").is_visible()
        assert "operator login" in page.inner_text("#readonly-note")
        # The editor and its preview work (they change nothing); sending and start/pause/stop do not.
        page.wait_for_selector("#preview[data-state='ok'] #preview-frames")
        assert page.inner_text("#preview-frames") == str(trex_subsampled().n_frames)
        assert page.locator("#send-schedule").is_disabled()
        assert "log in as operator" in page.get_attribute("#send-schedule", "title")
        for action in ("start", "pause", "resume", "stop"):
            button = page.locator(f"#actions [data-action={action}]")
            assert button.is_disabled() and "log in as operator" in button.get_attribute("title")
        # Even a hand-made request without the token is refused by the server.
        status = page.evaluate(
            """() => fetch('/api/modules/A/commands', {method: 'POST', body: '{"action": "stop"}',
                     headers: {'Content-Type': 'application/json'}}).then(r => r.status)"""
        )
        assert status == 401
        # trex-subsampled's runs (60.4 s a colour) are a little longer than the LEM's 60 s: the module
        # takes what a turn leaves at the next, and the page says how many since its start.
        deferred = page.locator("#deferred-shots")
        deferred.wait_for(timeout=60_000)
        assert "taken at a later turn of their colour" in deferred.inner_text()
        page.screenshot(path=artifacts / "control-read-only.png", full_page=True)
        # The full T-REX grid takes ~25 min of shots a colour: the preview says the LEM's 60 s turns
        # spread it, and what that means for a visit, before anyone sends it.
        page.select_option("#start-from", "preset:trex")
        warning = page.locator("#preview-warnings:has-text('several turns of a colour')")
        warning.wait_for()
        assert "part of the settings" in warning.inner_text()
        assert page.inner_text("#preview-busy") == "100 %"
        page.locator("#preview").screenshot(path=artifacts / "control-preview-warning.png")
    assert commands(control_system) == []


def test_an_invalid_schedule_shows_the_servers_reason_at_the_field_and_sends_nothing(
    browser: Any, control_system: System, artifacts: Path
) -> None:
    with camcal_page(browser, control_system) as page:
        open_control(page, control_system)
        login(page, control_system)
        page.select_option("#start-from", "preset:quick-check")
        page.wait_for_selector("#preview[data-state='ok']")

        # Beyond the camera's range: the server's reason, at the exposures.
        page.fill("[name='exposures_s']", "0.05, 5")
        page.click("#send-schedule")
        page.wait_for_selector("[data-error-for='exposures_s']:has-text(\"outside the camera's range\")")
        assert page.locator("[data-field='exposures_s']").get_attribute("class").count("invalid") == 1
        assert page.locator("#confirm-dialog").count() == 0, (
            "a schedule with problems must not reach the confirm step"
        )
        assert "Not sent" in page.inner_text("#send-note")

        # Not a schedule at all (repeats 0): the server's validation message, at the repeats.
        page.fill("[name='exposures_s']", "0.05, 0.07")
        page.fill("[name='repeats']", "0")
        page.wait_for_selector("[data-error-for='repeats']:has-text('greater than or equal to 1')")
        assert page.inner_text("[data-error-for='exposures_s']") == ""

        # A block's gain off the camera's 0.1 dB step: at that block's gains.
        page.fill("[name='repeats']", "2")
        page.click("#add-block")
        page.fill("[name='blocks.0.exposures_s']", "0.05")
        page.fill("[name='blocks.0.gains_db']", "4, 2.05")
        page.wait_for_selector("[data-error-for='blocks.0.gains_db']:has-text('0.1 dB step')")
        page.click("#send-schedule")
        page.wait_for_selector("#send-note:has-text('Not sent')")
        assert page.locator("#confirm-dialog").count() == 0
        hide_toast(page)
        page.locator("#editor-panel").screenshot(path=artifacts / "control-invalid-field.png")
    assert commands(control_system) == []


#: What the module panel and its tab say at the moment the tracker shows a command done.
WATCH_DONE = """() => {
  window.atDone = [];
  const t = document.querySelector('#tracker');
  window.doneObserver?.disconnect();
  window.doneObserver = new MutationObserver(() => {
    if (t.dataset.state !== 'done' || window.atDone.some(([id]) => id === t.dataset.commandId)) return;
    const tab = document.querySelector("#module-tabs [data-module='A'] small");
    window.atDone.push([t.dataset.commandId, document.querySelector('#current-schedule').textContent,
                        tab ? tab.textContent.trim() : '']);
  });
  window.doneObserver.observe(t, { attributes: true, attributeFilter: ['data-state', 'data-command-id'] });
}"""


def send_schedule(
    page: Any, preset: str, apply: str, expect: str, artifacts: Path, shot: str, warning: str | None = None
) -> str:
    """Load a preset, send it, check the confirm step says ``expect`` (and warns with ``warning``, or
    not at all when it is None), confirm; the command's id."""
    page.select_option("#start-from", f"preset:{preset}")
    page.wait_for_function("n => document.querySelector('[name=name]').value === n", arg=preset)
    page.wait_for_function(
        "n => document.querySelector('#preview-frames')?.textContent === n",
        arg=str({"linearity-scan": linearity_scan(), "trex-subsampled": trex_subsampled()}[preset].n_frames),
    )
    page.check(f"input[name='apply'][value='{apply}']")
    page.click("#send-schedule")
    dialog = page.locator("#confirm-dialog")
    dialog.wait_for()
    assert dialog.locator("#confirm-message").inner_text() == expect
    details = dialog.locator(".confirm-details").inner_text()
    if warning is None:
        assert "Warning" not in details, details
    else:
        assert f"Warning: then {warning}" in details, details
    page.screenshot(path=artifacts / shot)
    page.evaluate(WATCH_TRACKER)
    page.evaluate(WATCH_DONE)
    page.click("#confirm-ok")
    page.wait_for_selector("#send-note:has-text('Sent as command')")
    # the editor now holds what was sent, and says so (it kept naming where the edit had started)
    assert page.inner_text("#start-note").startswith(f"Sent: {preset} v"), page.inner_text("#start-note")
    return page.get_attribute("#tracker", "data-command-id")


def wait_done(page: Any, command_id: str, timeout_s: float = 45) -> list[str]:
    page.wait_for_selector(
        f"#tracker[data-command-id='{command_id}'][data-state='done']", timeout=timeout_s * 1000
    )
    page.wait_for_selector(f"#commands-table tr[data-command-id='{command_id}'] .state-done")
    seen = [state for cid, state in page.evaluate("window.trackerStates") if cid == command_id]
    assert seen[-1] == "done" and seen == sorted(seen, key=STEPS.index), f"states out of order: {seen}"
    return seen


def newest_frames(system: System, version: int) -> list[dict[str, Any]]:
    items = api(system, "/api/frames?module=A&order=newest&limit=100")["items"]
    return [f for f in items if f["schedule_version"] == version]


def test_move_module_a_to_the_linearity_scan_and_back(
    browser: Any, control_system: System, artifacts: Path
) -> None:
    system = control_system
    original = api(system, "/api/health")["modules"]["A"]["schedule"]
    assert original["name"] == "trex-subsampled"
    v0 = original["version"]
    scan = linearity_scan()
    trex = trex_subsampled()
    with camcal_page(browser, system) as page:
        open_control(page, system)
        login(page, system)
        # The preview judges settings from the frames seen so far: wait until there are some.
        page.wait_for_selector(
            "#preview .preview-module[data-module='A'] td[data-verdict='ok']", timeout=60_000
        )

        # 1. To the linearity scan at the end of the current setting.
        scan_id = send_schedule(
            page,
            "linearity-scan",
            "end_of_setting",
            f"Module A will switch from trex-subsampled v{v0} to linearity-scan v{v0 + 1} "
            "at the end of the current setting.",
            artifacts,
            "control-confirm-schedule.png",
            warning=f"LRM-A runs linearity-scan v{v0 + 1}, LRM-B runs trex-subsampled v1: ",
        )
        # Sent: Send stays off while the form holds what was sent; a change brings it back, and the
        # change undone is what was sent again.
        send = page.locator("#send-schedule")
        assert send.is_disabled() and send.inner_text() == "Sent to LRM-A ✓", send.inner_text()
        assert "change the schedule" in send.get_attribute("title")
        repeats = page.input_value("[name='repeats']")
        page.fill("[name='repeats']", str(int(repeats) + 1))
        page.wait_for_function("() => !document.querySelector('#send-schedule').disabled")
        assert page.inner_text("#send-schedule") == "Send to LRM-A…"
        page.fill("[name='repeats']", repeats)
        page.wait_for_function("() => document.querySelector('#send-schedule').disabled")
        page.screenshot(path=artifacts / "control-command-in-flight.png", full_page=True)
        seen = wait_done(page, scan_id)
        assert "in_progress" in seen or "accepted" in seen, seen
        # The moment the module says done, its panel and tab name the new schedule (no heartbeat waited for).
        at_done = {cid: (panel, tab) for cid, panel, tab in page.evaluate("window.atDone")}
        assert at_done[scan_id] == (f"linearity-scan v{v0 + 1}", f"linearity-scan v{v0 + 1}"), at_done
        assert "Done: LRM-A runs linearity-scan" in page.inner_text("#tracker-text")
        # A and B now run schedules of different settings: the panel says what λ_att loses.
        mismatch = page.locator("#schedule-mismatch")
        mismatch.wait_for()
        text = mismatch.inner_text()
        assert f"LRM-A runs linearity-scan v{v0 + 1}, LRM-B runs trex-subsampled v1" in text, text
        assert "λ_att" in text and "setting" in text, text
        # The frames change settings: the scan's exposures and gains, with the new version.
        frames = wait_until(
            lambda: len(newest_frames(system, v0 + 1)) >= 4 and newest_frames(system, v0 + 1),
            40,
            "scan frames",
        )
        settings = {(e, g) for e, g, _ in scan.settings()}
        assert {(f["exposure_s"], f["gain_db"]) for f in frames} <= settings
        page.wait_for_selector(f"#recent-frames li.current[data-version='{v0 + 1}']")
        hide_toast(page)
        page.screenshot(path=artifacts / "control-done-linearity-scan.png", full_page=True)

        # The live card says so too.
        page.goto(system.url("/"))
        page.wait_for_selector(f"#module-A [data-field='schedule']:has-text('linearity-scan v{v0 + 1}')")
        page.locator("#module-A").screenshot(path=artifacts / "live-card-linearity-scan.png")

        # 2. Back to the original schedule, now.
        open_control(page, system)
        back_id = send_schedule(
            page,
            "trex-subsampled",
            "now",
            f"Module A will switch from linearity-scan v{v0 + 1} to trex-subsampled v{v0 + 2} now.",
            artifacts,
            "control-confirm-back.png",
        )
        wait_done(page, back_id)
        at_done = {cid: (panel, tab) for cid, panel, tab in page.evaluate("window.atDone")}
        assert at_done[back_id][0] == f"trex-subsampled v{v0 + 2}", at_done
        page.wait_for_selector(f"#current-schedule:has-text('trex-subsampled v{v0 + 2}')")
        page.wait_for_selector("#schedule-mismatch", state="detached")  # the same settings again
        frames = wait_until(
            lambda: len(newest_frames(system, v0 + 2)) >= 2 and newest_frames(system, v0 + 2), 40, "frames"
        )
        assert {(f["exposure_s"], f["gain_db"]) for f in frames} <= {(e, g) for e, g, _ in trex.settings()}

        # 3. Pause (confirmed) while the module is offline: pending, and the page says why; the
        #    command is delivered once the module is back. Then resume (no confirmation asked).
        pid = module_pid(system, "A")
        os.kill(pid, signal.SIGSTOP)
        try:
            page.wait_for_selector("#module-link[data-link='down']", timeout=30_000)
            page.evaluate(WATCH_TRACKER)
            page.click("#actions [data-action=pause]")
            page.locator("#confirm-dialog").wait_for()
            assert page.inner_text("#confirm-message").startswith(
                f"Module A will pause trex-subsampled v{v0 + 2}"
            )
            assert "LRM-A is offline" in page.inner_text("#confirm-dialog .confirm-details")
            page.locator("#confirm-dialog").screenshot(path=artifacts / "control-confirm-pause-offline.png")
            page.click("#confirm-ok")
            page.wait_for_selector("#tracker[data-state='pending'] #tracker-text.offline")
            assert "LRM-A is offline" in page.inner_text("#tracker-text")
            pause_id = page.get_attribute("#tracker", "data-command-id")
            page.wait_for_timeout(1500)
            assert api(system, f"/api/commands/{pause_id}")["state"] == "pending"
            hide_toast(page)
            page.screenshot(path=artifacts / "control-pending-offline.png", full_page=True)
        finally:
            os.kill(pid, signal.SIGCONT)
        seen = wait_done(page, pause_id)
        assert seen[0] == "pending", seen
        page.wait_for_selector("text=Done: LRM-A paused")
        page.wait_for_selector("#run-state:has-text('paused')")
        assert page.locator("#actions [data-action=resume]").is_enabled()
        assert page.locator("#actions [data-action=pause]").is_disabled()
        page.click("#actions [data-action=resume]")
        page.wait_for_selector("#tracker[data-state='done'] >> text=Done: LRM-A resumed")
        resume_id = page.get_attribute("#tracker", "data-command-id")
        page.wait_for_selector("#run-state:has-text('running')")
        hide_toast(page)
        page.screenshot(path=artifacts / "control-after-pause-resume.png", full_page=True)

        # 4. The audit log records each command and the module's answers, in the API ...
        ids = {scan_id: "set_schedule", back_id: "set_schedule", pause_id: "pause", resume_id: "resume"}
        audit = api(system, "/api/audit?limit=500")
        for cid, action in ids.items():
            mine = [a for a in audit if a["details"].get("command_id") == cid]
            by_who = {(a["actor"], a["action"]) for a in mine}
            assert (system.operator, f"command.{action}") in by_who, cid
            assert ("module:A", "command.accepted") in by_who and ("module:A", "command.done") in by_who, (
                by_who
            )
        # ... in the review view ...
        page.goto(system.url("/review#tab=audit"))
        for cid, action in ids.items():
            page.wait_for_selector(f"#audit-table tr:has-text('command.{action}'):has-text('#{cid[:8]}')")
            answer = page.locator(f"#audit-table tr:has-text('command.done'):has-text('#{cid[:8]}')")
            assert "LRM-A (module)" in answer.inner_text() and "applied" in answer.inner_text()
        sent = page.locator(f"#audit-table tr:has-text('#{scan_id[:8]}'):has-text('command.set_schedule')")
        assert f"sent linearity-scan v{v0 + 1}" in sent.inner_text()
        page.select_option("#audit-kind", "answer")
        page.wait_for_function(
            """() => [...document.querySelectorAll('#audit-table tbody tr[data-kind]')]
                     .every(r => r.dataset.kind === 'answer')"""
        )
        page.select_option("#audit-kind", "")
        page.wait_for_selector("#audit-table tr[data-kind='command']")
        page.screenshot(path=artifacts / "review-audit-commands.png", full_page=True)
        # ... and in its CSV export.
        assert page.get_attribute("#audit-export", "href") == "/api/audit/export"
        with page.expect_download() as dl:
            page.click("#audit-export")
        rows = list(csv.DictReader(io.StringIO(Path(dl.value.path()).read_text())))
        for cid in ids:
            assert {r["action"] for r in rows if cid in r["details"]} >= {"command.accepted", "command.done"}


def test_a_command_the_module_refuses_shows_rejected_with_the_modules_reason(
    browser: Any, control_system: System, artifacts: Path
) -> None:
    """A schedule command the module refuses (here: one queued straight into the store, as a
    stale tool might, for the version the module already runs; the server's API would have
    refused it) ends rejected, and the page says so and gives the module's reason."""
    system = control_system
    running = wait_until(
        lambda: (api(system, "/api/health")["modules"].get("A") or {}).get("schedule"), 60, "module A"
    )
    version = running["version"]
    sched = trex_subsampled().model_copy(update={"version": version})
    store = Store.open(system.data)
    try:
        cmd = store.create_command(
            uuid.uuid4().hex,
            "A",
            "set_schedule",
            "stale-tool",
            payload={"schedule": sched.model_dump(mode="json")},
            target_version=version,
        )
    finally:
        store.close()
    answered = wait_until(
        lambda: (c := api(system, f"/api/commands/{cmd['id']}"))["state"] in ("done", "rejected") and c,
        40,
        "the module's answer",
    )
    reason = f"version {version} is not newer than the running version {version}"
    assert (answered["state"], answered["reason"]) == ("rejected", reason)
    with camcal_page(browser, system) as page:
        open_control(page, system)  # follows the module's newest command: the refused one
        page.wait_for_selector(f"#tracker[data-state='rejected'][data-command-id='{cmd['id']}']")
        assert page.inner_text("#tracker-text") == f"Rejected by LRM-A: {reason}."
        assert page.locator("#tracker [data-step='rejected']").is_visible()
        assert page.locator("#tracker [data-step='done']").count() == 0
        row = page.locator(f"#commands-table tr[data-command-id='{cmd['id']}']")
        assert row.locator(".cmd-state").inner_text() == "rejected"
        assert page.inner_text(f"#commands-table tr[data-reason-for='{cmd['id']}']") == reason
        page.wait_for_selector(f"#current-schedule:has-text('v{version}')")  # still what it ran
        hide_toast(page)
        page.screenshot(path=artifacts / "control-rejected.png", full_page=True)
