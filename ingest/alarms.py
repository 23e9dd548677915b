"""Alarm rules: what the deck crew must see, with severities MINOR and MAJOR.

The evaluator keeps a little state per module and, when asked, returns the
full set of conditions that hold now; the service raises the new ones and
clears the ones that stopped. (INVALID, for stale data, is the display's
verdict on old values, not a rule here.)
"""

from __future__ import annotations

import time
from collections import defaultdict, deque
from dataclasses import dataclass, field

import numpy as np

from camcal.core.frameset import CLOCK_OFFSET_MAX_S
from camcal.core.wire.limits import TIME_MIN_UNIX_S


@dataclass(frozen=True)
class AlarmLimits:
    """Thresholds of the rules, all configurable."""

    link_timeout_s: float = 5.0
    tilt_minor_deg: float = 3.0
    tilt_major_deg: float = 6.0
    humidity_minor_pct: float = 50.0
    humidity_major_pct: float = 70.0
    humidity_rise_pct_per_min: float = 0.5
    humidity_trend_s: float = 300.0
    edge_margin_fraction: float = 0.08
    reject_window_frames: int = 60
    reject_fraction: float = 0.8
    gap_age_s: float = 30.0
    disk_min_free_gb: float = 5.0
    conflict_hold_s: float = 900.0
    analysis_crash_hold_s: float = 900.0
    card_hold_s: float = 120.0  # how long a card, camera or sensor failure stays an alarm
    analysis_crash_major: int = 3
    clock_minor_s: float = 2.0
    clock_major_s: float = 10.0
    #: A running module's next frame may come this much later than the wait it says its schedule
    #: allows (the LEM's colour, the pause between passes) before "no frames" is raised.
    no_frame_grace_s: float = 120.0


#: Messages of a module waiting on its card beyond which "no frames" says its frames do not reach
#: the ship (a few are always under way: sensor batches, the frame being sent).
NO_FRAMES_PENDING = 10


@dataclass(frozen=True)
class Condition:
    """An alarm condition that holds now."""

    key: str
    kind: str
    severity: str
    message: str
    module: str | None


@dataclass
class _ModuleState:
    linked: bool = False
    signed_off: bool = False
    last_seen_unix_s: float | None = None
    conflicts: deque[tuple[float, str, int]] = field(default_factory=lambda: deque(maxlen=1000))
    humidity: deque[tuple[float, float]] = field(default_factory=lambda: deque(maxlen=4000))
    tilt_deg: float | None = None
    #: Per wavelength, the outcomes of its last frames ("ok" or the reason a frame was rejected).
    outcomes: dict[int, deque[str]] = field(default_factory=dict)
    near_edge: deque[bool] = field(default_factory=lambda: deque(maxlen=10))
    open_gaps: list[tuple[int, int, float]] = field(default_factory=list)
    #: Per device (``card``, ``camera``, ``sensors``): boot, failures this boot, the last error, and
    #: when that count last rose (`AlarmEvaluator.observe_failures`).
    failures: dict[str, tuple[str, int, str | None, float | None]] = field(default_factory=dict)
    clock_offset_s: float | None = None  # its clock minus the ship's, from its heartbeats
    #: What it says it runs and why it waits (`observe_production`), and since when (the ship's
    #: clock) a frame is due: its last frame, or when it began to run here.
    production: tuple[dict[str, object], dict[str, object] | None, int] | None = None
    frame_due_from: float | None = None
    clock_shown: tuple[str, float] | None = None  # the clock alarm's severity and the offset it names


class AlarmEvaluator:
    """Turns observations into the set of alarm conditions that hold."""

    def __init__(self, limits: AlarmLimits | None = None) -> None:
        self.limits = limits or AlarmLimits()
        self._m: dict[str, _ModuleState] = defaultdict(_ModuleState)
        self._disk_free_gb: float | None = None
        self._analysis_crashes: list[tuple[float, str]] = []

    # -- observations ----------------------------------------------------
    def observe_link(
        self, module: str, linked: bool, last_seen_unix_s: float | None, signed_off: bool = False
    ) -> None:
        """``signed_off``: the module said ``bye`` (shown as INFO, not as a lost link)."""
        st = self._m[module]
        if linked and not st.linked:
            st.frame_due_from = None  # back from an outage: its next frame is due from now
        st.linked, st.last_seen_unix_s, st.signed_off = linked, last_seen_unix_s, signed_off and not linked

    def observe_conflict(self, module: str, boot: str, seq: int, t_unix_s: float) -> None:
        """A message resent with other content than the stored copy."""
        self._m[module].conflicts.append((t_unix_s, boot, seq))

    def observe_humidity(self, module: str, t_unix_s: float, humidity_pct: float) -> None:
        self._m[module].humidity.append((t_unix_s, humidity_pct))

    def observe_tilt(self, module: str, tilt_deg: float) -> None:
        self._m[module].tilt_deg = tilt_deg

    def observe_frame(
        self,
        module: str,
        status: str,
        reason: str | None,
        centroid_px: tuple[float, float] | None,
        radius_px: float | None,
        size_px: tuple[int, int],
        wavelength_nm: int = 0,
    ) -> None:
        st = self._m[module]
        window = st.outcomes.setdefault(wavelength_nm, deque(maxlen=self.limits.reject_window_frames))
        window.append("ok" if status == "ok" else (reason or "rejected"))
        if reason == "off_edge":
            st.near_edge.append(True)
        elif centroid_px is not None and radius_px is not None:
            w, h = size_px
            margin = self.limits.edge_margin_fraction * min(w, h)
            x, y = centroid_px
            edge = min(x, y, w - 1 - x, h - 1 - y) - radius_px
            st.near_edge.append(edge < margin)
        elif reason == "no_source":
            st.near_edge.append(False)

    def observe_disk(self, free_gb: float) -> None:
        self._disk_free_gb = free_gb

    def observe_analysis_crashes(self, crashes: list[tuple[float, str]]) -> None:
        """The ingest's analysis processes that died: (unix time, what happened), oldest first."""
        self._analysis_crashes = crashes

    def observe_failures(self, device: str, module: str, boot: str, count: int, error: str | None) -> None:
        """What the module's heartbeat says of a device: its SD card (messages it could not keep),
        its camera (captures that failed) or its sensors (reads that failed), this boot."""
        st = self._m[module]
        last_boot, last_count, _, rose = st.failures.get(device, ("", 0, None, None))
        if count and (boot != last_boot or count > last_count):
            rose = time.time()
        st.failures[device] = (boot, count, error, rose)

    def observe_clock(self, module: str, offset_s: float | None) -> None:
        """The module's clock minus the ship's, as its heartbeats say (None: not known yet)."""
        self._m[module].clock_offset_s = offset_s

    def observe_production(
        self,
        module: str,
        schedule: dict[str, object],
        waiting: dict[str, object] | None,
        last_frame_unix_s: float | None,
        outbox_pending: int,
        now_unix_s: float,
    ) -> None:
        """What a linked module's heartbeat says it runs and why it waits, and when its last frame
        came: a module that runs its schedule where captures are on owes a frame within the wait it
        names plus `AlarmLimits.no_frame_grace_s`."""
        st = self._m[module]
        before = st.production[0] if st.production else None
        running = schedule.get("state") == "running"
        here = not (waiting and waiting.get("reason") == "not_here")
        changed = before is None or (before.get("state"), before.get("version")) != (
            schedule.get("state"),
            schedule.get("version"),
        )
        if not running or not here or changed or st.frame_due_from is None:
            st.frame_due_from = now_unix_s  # the wait starts (again) now
        if last_frame_unix_s is not None:
            st.frame_due_from = max(st.frame_due_from, last_frame_unix_s)
        st.production = (dict(schedule), dict(waiting) if waiting else None, outbox_pending)

    def observe_gaps(self, module: str, gaps: list[tuple[int, int, float]]) -> None:
        self._m[module].open_gaps = gaps

    # -- evaluation ------------------------------------------------------
    def evaluate(self, now_unix_s: float) -> dict[str, Condition]:
        lim = self.limits
        out: dict[str, Condition] = {}
        if self._disk_free_gb is not None and self._disk_free_gb < lim.disk_min_free_gb:
            out["disk:ship"] = Condition(
                "disk:ship",
                "disk",
                "MAJOR",
                f"only {self._disk_free_gb:.1f} GB free in the data folder "
                f"(limit {lim.disk_min_free_gb:g} GB): "
                "export and remove old dives, or set a retention",
                None,
            )

        died = [c for c in self._analysis_crashes if now_unix_s - c[0] <= lim.analysis_crash_hold_s]
        if died:
            out["analysis_crash:ship"] = Condition(
                "analysis_crash:ship",
                "analysis_crash",
                "MAJOR" if len(died) >= lim.analysis_crash_major else "MINOR",
                f"{len(died)} analysis process(es) died since {_hms(died[0][0])} UTC (latest: "
                f"{died[-1][1]}) and were replaced; every frame is kept and analysed again. If it "
                "repeats, check the ship computer's memory (`dmesg` for the OOM killer)",
                None,
            )

        def add(kind: str, module: str, severity: str, message: str) -> None:
            key = f"{kind}:{module}"
            out[key] = Condition(key, kind, severity, message, module)

        for module, st in self._m.items():
            if st.last_seen_unix_s is not None:
                age = now_unix_s - st.last_seen_unix_s
                # Messages name times, not ages: an alarm's row and event change when its state does,
                # not every second.
                since = _hms(st.last_seen_unix_s)
                if st.signed_off:
                    add("signed_off", module, "INFO", f"module {module} signed off at {since} UTC")
                elif not st.linked or age > lim.link_timeout_s:
                    add(
                        "link_lost",
                        module,
                        "MAJOR",
                        f"module {module}: no packet since {since} UTC; check the fibre link and power",
                    )
            conflicts = [c for c in st.conflicts if now_unix_s - c[0] <= lim.conflict_hold_s]
            if conflicts:
                _, boot, seq = conflicts[-1]
                add(
                    "conflict",
                    module,
                    "MAJOR",
                    f"module {module}: {len(conflicts)} message(s) resent with other content than the "
                    f"stored copy since {_hms(conflicts[0][0])} UTC (latest {boot}/{seq}); the ship keeps "
                    "the first: compare the module's SD card with `camcal import`",
                )
            if st.humidity:
                t_last, h_last = st.humidity[-1]
                recent = [(t, h) for t, h in st.humidity if t >= t_last - lim.humidity_trend_s]
                rise = None
                if len(recent) >= 10 and recent[-1][0] - recent[0][0] >= 60:
                    rise = _slope_per_min(recent)
                if h_last >= lim.humidity_major_pct:
                    add(
                        "humidity",
                        module,
                        "MAJOR",
                        f"module {module}: housing humidity {h_last:.0f} % — possible leak, "
                        "recover the module",
                    )
                elif rise is not None and rise >= lim.humidity_rise_pct_per_min:
                    add(
                        "humidity",
                        module,
                        "MAJOR",
                        f"module {module}: housing humidity rising {rise:.1f} %/min — possible leak",
                    )
                elif h_last >= lim.humidity_minor_pct:
                    add("humidity", module, "MINOR", f"module {module}: housing humidity {h_last:.0f} %")
            if st.tilt_deg is not None:
                if st.tilt_deg >= lim.tilt_major_deg:
                    add(
                        "tilt",
                        module,
                        "MAJOR",
                        f"module {module}: tilted {st.tilt_deg:.1f}° (limit {lim.tilt_major_deg:g}°)",
                    )
                elif st.tilt_deg >= lim.tilt_minor_deg:
                    add(
                        "tilt",
                        module,
                        "MINOR",
                        f"module {module}: tilted {st.tilt_deg:.1f}° (limit {lim.tilt_minor_deg:g}°)",
                    )
            if len(st.near_edge) >= 3 and sum(st.near_edge) >= 0.6 * len(st.near_edge):
                add(
                    "lem_leaving_view",
                    module,
                    "MINOR",
                    f"module {module}: the LEM is near or past the edge of the view",
                )
            # A schedule that sweeps exposures and gains saturates many of its frames by design (the
            # near camera most): that is no fault. The fault is a wavelength of which no recent frame
            # is usable, so that no λ_att can come from it; said once per module, worst first.
            unusable = []
            for wl, window in sorted(st.outcomes.items()):
                n = len(window)
                if n < max(10, lim.reject_window_frames // 3) or "ok" in window:
                    continue
                for reason, what, advice in (
                    ("saturated", "saturated", "shorten exposures or lower gains"),
                    ("too_dark", "too dark", "lengthen exposures or raise gains"),
                ):
                    frac = sum(1 for o in window if o == reason) / n
                    if frac >= lim.reject_fraction:
                        unusable.append((reason, frac, wl, n, what, advice))
            for reason in ("saturated", "too_dark"):
                found = sorted((u for u in unusable if u[0] == reason), key=lambda u: -u[1])
                if found:
                    _, frac, wl, n, what, advice = found[0]
                    where = ", ".join(f"{u[2]} nm" for u in sorted(found, key=lambda u: u[2]) if u[2])
                    add(
                        f"frames_{reason}",
                        module,
                        "MINOR",
                        f"module {module}: none of the last {n} frames{f' at {where}' if where else ''} "
                        f"usable ({100 * frac:.0f} % {what}): no λ_att from them; {advice}",
                    )
            for device, (_, count, error, rose) in st.failures.items():
                if rose is not None and now_unix_s - rose <= lim.card_hold_s:
                    add(device, module, "MAJOR", _failure_message(device, module, count, error, _hms(rose)))
            silent = self._no_frames(module, st, now_unix_s)
            if silent is not None:
                add("no_frames", module, "MAJOR", silent)
            clock = self._clock(st)
            if clock is not None:
                add("clock", module, clock[0], _clock_message(module, clock[0], clock[1], now_unix_s))
            old = [g for g in st.open_gaps if now_unix_s - g[2] >= lim.gap_age_s]
            if old:
                missing = sum(b - a + 1 for a, b, _ in old)
                add(
                    "sequence_gap",
                    module,
                    "MINOR",
                    f"module {module}: {missing} message(s) missing in {len(old)} gap(s); "
                    "they will arrive when the link recovers, or import the SD card",
                )
        return out

    def _no_frames(self, module: str, st: _ModuleState, now_unix_s: float) -> str | None:
        """The "no frames" alarm's message: a linked module that runs its schedule where it takes
        pictures and has sent no frame for longer than the wait it names allows; with the reason."""
        if not st.linked or st.production is None or st.frame_due_from is None:
            return None
        schedule, waiting, pending = st.production
        if schedule.get("state") != "running" or (waiting and waiting.get("reason") == "not_here"):
            return None
        allowed = float(waiting.get("for_s") or 0.0) if waiting else 0.0  # type: ignore[arg-type]
        if now_unix_s - st.frame_due_from <= allowed + self.limits.no_frame_grace_s:
            return None
        runs = f"runs schedule {schedule.get('name') or '?'} (version {schedule.get('version')})"
        since = _hms(st.frame_due_from)
        if pending >= NO_FRAMES_PENDING:
            why = (
                f"{pending} of its messages wait on its SD card, unsent or not acknowledged: its frames "
                "do not reach the ship (the link, or the ship's store: `camcal doctor`)"
            )
        elif waiting and waiting.get("reason") == "lem":
            why = (
                f"it keeps waiting for the LEM's {waiting.get('wavelength_nm')} nm: check the LEM and the "
                "module's clock (its timetable says when the LEM shows which colour)"
            )
        elif waiting and waiting.get("reason") == "pause":
            why = "it keeps pausing between passes: check the schedule's pause"
        else:
            why = (
                "it takes no picture though its schedule calls for one (its camera or its schedule runner "
                "hangs): restart the module; its SD card keeps everything"
            )
        return f"module {module} {runs} but has sent no frame since {since} UTC: {why}"

    def _clock(self, st: _ModuleState) -> tuple[str, float] | None:
        """The clock alarm of a linked module: its severity and the offset its message names (the
        one when it began or changed severity, so that the message does not change every beat)."""
        off, lim = st.clock_offset_s, self.limits
        severity = None
        if st.linked and off is not None and abs(off) >= lim.clock_minor_s:
            severity = "MAJOR" if abs(off) >= lim.clock_major_s else "MINOR"
        if severity is None:
            st.clock_shown = None
        elif st.clock_shown is None or st.clock_shown[0] != severity:
            st.clock_shown = (severity, off)  # type: ignore[assignment]
        return st.clock_shown


def _clock_message(module: str, severity: str, off: float, now_unix_s: float) -> str:
    """The clock alarm's message: how far off, what it does to the science, what to do."""
    reads = now_unix_s + off
    if reads < TIME_MIN_UNIX_S:  # never set: a Raspberry Pi without its clock's battery starts at 1970
        return (
            f"module {module}: its clock is not set (it reads {utc_minute(reads)} UTC): its frames and "
            "sensor readings cannot be placed in time and are not taken (they stay on its SD card; "
            "the humidity (leak) and tilt alarms are blind for it); set its clock from the ship (NTP) "
            "and restart it. After the dive, its card imports at the right times: "
            f"camcal import CARD --clock-offset {module}={off:+.0f}"
        )
    side = "ahead of" if off > 0 else "behind"
    message = f"module {module}: its clock is {abs(off):.0f} s {side} the ship's; sync it (NTP)"
    if severity != "MAJOR":
        return message
    message += (
        ": λ_att pairs the two cameras' frames by their times, and frames this far apart are paired "
        "with the wrong moments or not at all"
    )
    if abs(off) <= CLOCK_OFFSET_MAX_S:
        return message + f" (repair them afterwards: camcal reanalyze --clock-offset {module}={off:+.0f})"
    return message + f" (its clock reads {utc_minute(reads)} UTC: set it and restart the module)"


def _slope_per_min(samples: list[tuple[float, float]]) -> float:
    """The least-squares slope of (t [s], value) samples, per minute.

    Not the two ends' difference: a sensor's 0.2 % of noise on each end of a one-minute window made
    0.3 %/min of noise on the rise, and a sealed housing's flat humidity raised the 0.5 %/min MAJOR
    leak alarm now and then (at `camcal up`'s start, cleared a second later).
    """
    t, v = np.array(samples, dtype=np.float64).T
    return 60.0 * float(np.polyfit(t - t[0], v, 1)[0])  # as `ingest.derived` takes a depth rate


def utc_minute(t_unix_s: float) -> str:
    """``YYYY-MM-DD HH:MM`` (UTC) of a time, 1970 at the earliest (a clock never set)."""
    return time.strftime("%Y-%m-%d %H:%M", time.gmtime(max(t_unix_s, 0.0)))


def _failure_message(device: str, module: str, count: int, error: str | None, at: str) -> str:
    """The (MAJOR) alarm's message of a device whose failures rose within ``card_hold_s``."""
    if device == "card":
        return (
            f"module {module}: its SD card cannot keep what it takes ({error or 'write failed'}); "
            f"{count} frame(s) and sensor message(s) not taken since its boot, the last at {at} UTC: "
            "free or swap the card at the next recovery (everything on it is kept)"
        )
    if device == "camera":
        return (
            f"module {module}: its camera failed {count} time(s) since its boot, the last at {at} UTC "
            f"({error or 'no frame'}); the module retries by itself: if no frames come, check the "
            "camera's cable and power"
        )
    return (
        f"module {module}: its sensors failed {count} time(s) since its boot, the last at {at} UTC "
        f"({error or 'read failed'}); the humidity (leak) and tilt alarms are blind while they fail: "
        "the module retries by itself, check the sensor board"
    )


def _hms(t_unix_s: float) -> str:
    return time.strftime("%H:%M:%S", time.gmtime(t_unix_s))
