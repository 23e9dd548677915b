"""A module whose clock is off: the ship measures the offset from its heartbeats and says so.

λ_att pairs the near and far cameras' frames by their capture times (`ingest.rolling`), so a
module clock a minute off pairs the wrong moments or none at all (measured: 10 s leaves the
points within 1 %, 30 s moves them by up to 1.5 %, 90 s leaves no point). The crew must see it.
"""

from __future__ import annotations

import subprocess
import sys
import time
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

from sqlalchemy import select

from ingest.service import IngestService
from storage.models import Alarm, Event
from tests.utils.live import cli_env, make_agent, wait_for
from tests.utils.rogue import IngestProbe
from tests.utils.system import wait_until

AHEAD_S = 60.0
DRIFT_S = 0.7


def clock_alarms(svc: IngestService) -> list[Alarm]:
    with svc.store.read() as s:
        return list(s.scalars(select(Alarm).where(Alarm.kind == "clock")))


def clock_events(svc: IngestService) -> int:
    with svc.store.read() as s:
        return sum(
            e.payload["kind"] == "clock" for e in s.scalars(select(Event).where(Event.kind == "alarm"))
        )


def test_a_module_clock_a_minute_ahead_raises_a_major_alarm_that_says_what_to_do(
    service: IngestService, tmp_path: Path
) -> None:
    good = make_agent("A", service.endpoint, tmp_path / "outbox-A")[0]
    ahead = make_agent("B", service.endpoint, tmp_path / "outbox-B")[0]
    send = ahead._send

    beats = []

    def sent_from_a_clock_ahead(sock: Any, msg: Any) -> None:  # the one stand-in: a module's RTC,
        if getattr(msg, "sent_at", None) is not None:  # a minute ahead and drifting 0.7 s a beat
            beats.append(msg)
            ahead_s = AHEAD_S + DRIFT_S * len(beats)
            msg = msg.model_copy(update={"sent_at": msg.sent_at + timedelta(seconds=ahead_s)})
        send(sock, msg)

    ahead._send = sent_from_a_clock_ahead  # type: ignore[method-assign]
    for a in (good, ahead):
        a.start()
    try:
        assert wait_for(lambda: clock_alarms(service), 20), "no clock alarm"
        (alarm,) = clock_alarms(service)
        assert alarm.module_id == "B" and alarm.severity == "MAJOR" and alarm.active
        assert "s ahead of the ship" in alarm.message and "NTP" in alarm.message
        named = float(alarm.message.split("its clock is ")[1].split(" s ")[0])
        assert AHEAD_S <= named <= AHEAD_S + 10 * DRIFT_S

        def offsets() -> dict[str, float | None]:
            return {m: h["clock_offset_s"] for m, h in service.health()["modules"].items()}

        # A's offset is known after its fifth beat: B's alarm may come first (seen on PostgreSQL)
        assert wait_for(lambda: offsets().get("A") is not None, 10), offsets()
        known = offsets()
        assert known["B"] is not None and known["B"] > AHEAD_S
        assert known["A"] is not None and abs(known["A"]) < 1.0
        # Raised once: its message names the offset it began with, not each beat's (no event a beat).
        assert not wait_for(lambda: clock_events(service) > 1, 4)
        assert good.counters["frames_captured"] > 0 and "A" not in {
            a.module_id for a in clock_alarms(service)
        }
    finally:
        for a in (good, ahead):
            a.stop()


def test_heartbeats_that_arrive_late_on_a_busy_link_are_not_taken_for_a_clock_behind(
    service: IngestService, tmp_path: Path
) -> None:
    """On a link saturated by a catch-up, a heartbeat waits behind frames and reads as a clock
    seconds behind; the estimate takes the least delayed recent beat, so no alarm is raised."""
    late = make_agent("B", service.endpoint, tmp_path / "outbox-B")[0]
    send = late._send
    beats = []

    def mostly_late(sock: Any, msg: Any) -> None:  # two beats in three as if 8 s in the queue
        if getattr(msg, "sent_at", None) is not None:
            beats.append(msg)
            if len(beats) % 3:
                msg = msg.model_copy(update={"sent_at": msg.sent_at - timedelta(seconds=8.0)})
        send(sock, msg)

    late._send = mostly_late  # type: ignore[method-assign]
    late.start()
    try:
        assert wait_for(lambda: len(beats) >= 8, 20)
        offset = service.health()["modules"]["B"]["clock_offset_s"]
        assert offset is not None and abs(offset) < 1.0, offset
        assert not clock_alarms(service)
    finally:
        late.stop()


#: A Raspberry Pi whose clock was never set (no battery, no NTP yet) reads 1970-01-01 at its boot.
NEVER_SET_S = datetime(1970, 1, 1, 0, 5, tzinfo=UTC).timestamp() - time.time()


def test_a_module_whose_clock_was_never_set_links_and_the_ship_says_what_to_do(tmp_path: Path) -> None:
    """Before, every `hello` of such a module was refused (`sent_at` before 2000): it never linked,
    no alarm said why, only the ship's log. Real ``camcal ingest`` and ``camcal lrm simulate``
    processes over CURVE; the module's clock error is the simulator's (the one stand-in)."""
    ship = IngestProbe(tmp_path / "data")
    module = None
    try:
        ship.wait_ready()
        args = [
            "lrm",
            "simulate",
            "--camera",
            "B",
            "--connect",
            ship.endpoint,
            "--outbox",
            str(tmp_path / "card"),
        ]
        args += [
            "--keys",
            str(ship.keys),
            "--speed",
            "50",
            "--frame-scale",
            "0.1",
            "--deck-s",
            "0",
            "--no-fsync",
        ]
        args += ["--clock-error-s", f"{NEVER_SET_S:.0f}"]
        log = tmp_path / "module.log"
        t0 = time.monotonic()
        with log.open("wb") as fh:
            module = subprocess.Popen(
                [sys.executable, "-c", "from camcal.cli import main; main()", *args],
                env=cli_env(),
                stdout=fh,
                stderr=subprocess.STDOUT,
            )

        def clock_alarm() -> Any:
            rows = ship.rows("SELECT severity, message FROM alarms WHERE kind = 'clock' AND module_id = 'B'")
            return (
                rows
                and ship.rows("SELECT COUNT(*) FROM frames")[0][0] == 0
                and _kept_from_1970(tmp_path / "card") >= 3
                and rows
            )

        ((severity, message),) = wait_until(
            clock_alarm, 60, "the clock alarm and refused frames", every_s=0.5
        )
        assert severity == "MAJOR"
        assert "its clock is not set (it reads 1970-01-01" in message and "NTP" in message
        assert "stay on its SD card" in message and "leak" in message  # its sensors are refused too
        named = float(message.split("--clock-offset B=")[1])  # what its card imports with
        assert abs(named - NEVER_SET_S) < 60, (named, NEVER_SET_S)
        health = ship.health()
        assert health["modules"]["B"]["link"] == "up", health["modules"]["B"]  # it links all the same
        assert health["modules"]["B"]["clock_offset_s"] < -1.7e9
        assert ship.rows("SELECT COUNT(*) FROM frames") == [(0,)]  # no frame placed in 1970
        assert ship.alive() and module.poll() is None
        # Every sensor batch is refused alike: the module's log (on its SD card) says so once per
        # 10 s with how many it left out, not once a message.
        refused = (tmp_path / "card" / "refused.jsonl").read_text().count("\n")
        lines = log.read_text().count("for good")
        assert refused >= 10 and lines <= (time.monotonic() - t0) / 10 + 2, (refused, lines)
    finally:
        if module is not None:
            module.kill()
            module.wait(10)
        ship.stop()


def _kept_from_1970(card: Path) -> int:
    """Frames on the module's card stamped 1970 (kept there: the module does not offer them)."""
    manifest = card / "frames" / "manifest.csv"
    return manifest.read_text().count(",1970-01-01T") if manifest.exists() else 0
