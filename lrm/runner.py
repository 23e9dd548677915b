"""Running an exposure schedule on a camera, and changing it safely while it runs."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any, Protocol

from camcal.core.schedule import Schedule, Shot, defer_rest_of_run

log = logging.getLogger("camcal.lrm")


class LemClock(Protocol):
    """Which wavelength the LEM shows when (its timetable, in wall-clock terms)."""

    def wavelength_at(self, t: datetime) -> int: ...

    def next_start_of(self, wavelength_nm: int, after: datetime) -> datetime: ...

    def next_change_after(self, t: datetime) -> datetime: ...


@dataclass(frozen=True)
class Capture:
    """A frame the runner took, with the shot of the schedule it belongs to."""

    frame: Any  # lrm.camera.CapturedFrame
    shot: Shot
    wavelength_nm: int
    schedule_version: int


class ScheduleRunner:
    """Takes the schedule's shots one after the other, pass after pass.

    The LEM cycles its wavelengths on its own timetable: before a shot at
    405 nm the runner waits until the LEM shows 405 nm, and no exposure is
    started that would end after the LEM changes colour (its frame would
    hold two colours' light). When the LEM moves on, or is about to, while
    the runner is amid one wavelength's consecutive shots (a pass
    that does not fit the LEM's dwell: a slow card, long exposures), the
    rest of those shots come first at that wavelength's next turn
    (`deferred_shots`, logged) and the runner goes on with the next
    wavelength now: waiting a whole LEM cycle for them would put the module
    out of step with the LEM and with the other camera, whose frames of the
    same visit λ_att needs. A schedule longer than the dwell thus takes its
    settings in turn over several visits. ``gate`` (if given)
    must be true for capturing (e.g. only at the test stops and on station).
    States: ``running``, ``paused`` (resumes where it stopped), ``stopped``
    (restarts the pass from the beginning on ``start``). A new schedule
    applies at once, or at the end of the current setting (after the last
    repeat of the exposure and gain being taken).
    """

    def __init__(
        self,
        camera: Any,
        clock: Any,
        schedule: Schedule,
        *,
        lem: LemClock | None = None,
        gate: Callable[[], bool] | None = None,
        state: str = "running",
    ) -> None:
        self.camera = camera
        self.clock = clock
        self.lem = lem
        self.gate = gate
        self._cv = threading.Condition()
        self._schedule = schedule
        self._shots = list(schedule.shots())
        self._index = 0
        self._state = state
        self._pending: Schedule | None = None
        self.on_change: Callable[[Schedule, str], None] | None = None
        #: The index of the shot taken last in this pass, while running (None after a pause, stop or swap).
        self._last_taken: int | None = None
        #: Shots deferred to their wavelength's next turn because the LEM moved on amid them.
        self.deferred_shots = 0
        #: Why no shot is being taken now: (reason, until on the clock's monotonic scale, wavelength).
        self._waiting: tuple[str, float, int | None] | None = None

    # ------------------------------------------------------------ status
    @property
    def schedule(self) -> Schedule:
        return self._schedule

    @property
    def state(self) -> str:
        return self._state

    def status(self) -> dict[str, Any]:
        with self._cv:
            return {"name": self._schedule.name, "version": self._schedule.version, "state": self._state}

    def waiting(self) -> dict[str, Any] | None:
        """Why the runner takes no picture now while it runs (`camcal.core.wire.Waiting`): captures
        off here (``not_here``), the LEM's colour (``lem``) or the pause between passes (``pause``),
        with the wait left in seconds of real time; None while it takes pictures (or does not run)."""
        w = self._waiting
        if w is None or self._state != "running":
            return None
        reason, until, wavelength = w
        speed = float(getattr(self.clock, "speed", 1.0))  # a simulated clock runs faster than real time
        left_s = max(0.0, (until - self.clock.monotonic()) / speed)
        return {"reason": reason, "for_s": round(left_s, 3), "wavelength_nm": wavelength}

    def _wait(self, reason: str, seconds: float, wavelength_nm: int | None = None) -> None:
        self._waiting = (reason, self.clock.monotonic() + seconds, wavelength_nm)

    # ------------------------------------------------------------ control
    def set_schedule(self, schedule: Schedule, apply: str = "now") -> None:
        with self._cv:
            if apply == "end_of_setting":
                self._pending = schedule
            else:
                self._swap(schedule)
            self._cv.notify_all()

    def _swap(self, schedule: Schedule) -> None:
        self._schedule = schedule
        self._shots = list(schedule.shots())
        self._index = 0
        self._last_taken = None
        self._pending = None
        if self.on_change:
            self.on_change(schedule, self._state)

    def pause(self) -> None:
        self._set_state("paused")

    def resume(self) -> None:
        self._set_state("running")

    def stop(self) -> None:
        with self._cv:
            self._index = 0
        self._set_state("stopped")

    def start(self) -> None:
        self._set_state("running")

    def _set_state(self, state: str) -> None:
        with self._cv:
            self._state = state
            self._last_taken = None  # resumed or restarted, the next shot waits for its wavelength
            self._cv.notify_all()
            if self.on_change:
                self.on_change(self._schedule, state)

    # ------------------------------------------------------------ capturing
    def next_capture(self, stop: threading.Event) -> Capture | None:
        """Block until the next shot is taken; None when ``stop`` is set."""
        while not stop.is_set():
            with self._cv:
                if self._state != "running":
                    self._cv.wait(0.2)
                    continue
                if not self._shots:
                    self._cv.wait(0.2)
                    continue
                if self._index >= len(self._shots):
                    self._index = 0
                    pause = self._schedule.pause_s
                else:
                    pause = 0.0
                shot = self._shots[self._index]
                version = self._schedule.version
            if pause > 0:
                self._wait("pause", pause)
                if self._sleep(pause, stop):
                    continue
            if self.gate is not None and not self.gate():
                self._wait("not_here", 1.0)
                self._sleep(1.0, stop)
                continue
            if self.lem is not None:
                now = self.clock.now()
                if self.lem.wavelength_at(now) != shot.wavelength_nm or not self._fits(now, shot.exposure_s):
                    if self._defer_rest_of_run(version):
                        continue
                    start = self.lem.next_start_of(shot.wavelength_nm, now)
                    wait_s = max((start - now).total_seconds(), 0.0) + 1e-3
                    self._wait("lem", wait_s, shot.wavelength_nm)
                    self._sleep(wait_s, stop)
                    continue
            self._waiting = None
            frame = self.camera.capture(shot.exposure_s, shot.gain_db)
            wavelength = frame.wavelength_nm
            if wavelength is None:
                wavelength = self.lem.wavelength_at(frame.captured_at) if self.lem else shot.wavelength_nm
            with self._cv:
                if version == self._schedule.version and self._index < len(self._shots):
                    self._last_taken = self._index
                    self._index += 1
                    following = self._shots[self._index] if self._index < len(self._shots) else None
                    end_of_setting = following is None or (
                        following.wavelength_nm,
                        following.exposure_s,
                        following.gain_db,
                    ) != (shot.wavelength_nm, shot.exposure_s, shot.gain_db)
                    if end_of_setting and self._pending is not None:
                        self._swap(self._pending)
            return Capture(frame, shot, int(wavelength), version)
        return None

    def _fits(self, now: datetime, exposure_s: float) -> bool:
        """Whether an exposure started now ends before the LEM changes colour.

        A frame exposed across a change would hold two colours' light under one colour's label.
        An exposure longer than a whole dwell can never fit: it is taken (as the timetable allows).
        """
        assert self.lem is not None
        change = self.lem.next_change_after(now)
        dwell_s = (self.lem.next_change_after(change) - change).total_seconds()
        return exposure_s >= dwell_s or now + timedelta(seconds=exposure_s) <= change

    def _defer_rest_of_run(self, version: int) -> bool:
        """Amid one wavelength's consecutive shots and the LEM moved on: defer the rest of them.

        The run of that wavelength's shots is turned so that the shots not yet taken come first at
        its next turn, and the runner goes on with the next wavelength's shots now. True when shots
        were deferred; False at the start of a wavelength's shots (the runner waits for them).
        """
        with self._cv:
            i = self._index
            if version != self._schedule.version or self._last_taken != i - 1:
                return False
            j = defer_rest_of_run(self._shots, i)
            if j is None:
                return False
            wl = self._shots[i - 1].wavelength_nm
            self._index = j
            self._last_taken = None
            self.deferred_shots += j - i
            if self._pending is not None:  # the setting being taken ends here
                self._swap(self._pending)
        log.info("the LEM leaves %d nm before %d shots of it: they come first at its next turn", wl, j - i)
        return True

    def _sleep(self, seconds: float, stop: threading.Event) -> bool:
        """Sleep clock time in slices, waking for stop or a change; True if interrupted."""
        end = self.clock.monotonic() + seconds
        version, state = self._schedule.version, self._state
        while not stop.is_set():
            left = end - self.clock.monotonic()
            if left <= 0:
                return False
            self.clock.sleep(min(left, 0.5))
            if self._schedule.version != version or self._state != state:
                return True
        return True


class LemTimetableClock:
    """A `LemClock` from a timetable in seconds since ``epoch`` (e.g. the dive start).

    ``settle_s`` delays the first shot after each change of colour (time for
    the LED to settle, or to interleave two modules' frames: one module at 0,
    the other half a frame later).
    """

    def __init__(self, timetable: Any, epoch: datetime, settle_s: float = 0.0) -> None:
        if not (settle_s >= 0 and settle_s < timetable.dwell_s):
            raise ValueError(f"settle_s must lie in [0, dwell_s={timetable.dwell_s}), got {settle_s}")
        self.timetable = timetable
        self.epoch = epoch
        self.settle_s = float(settle_s)

    def wavelength_at(self, t: datetime) -> int:
        return int(self.timetable.wavelength_at((t - self.epoch).total_seconds()))

    def next_start_of(self, wavelength_nm: int, after: datetime) -> datetime:
        s = self.timetable.next_start_of(wavelength_nm, (after - self.epoch).total_seconds())
        return self.epoch + timedelta(seconds=float(s) + self.settle_s)

    def next_change_after(self, t: datetime) -> datetime:
        s = self.timetable.next_change_after((t - self.epoch).total_seconds())
        return self.epoch + timedelta(seconds=float(s))
