"""A simulated module wired once: camera, schedule runner (at the LEM's timetable), sensors, agent.

``camcal lrm simulate``, the live tests and the shared test dive build their
modules here, so a simulated module is the same everywhere.
"""

from __future__ import annotations

from camcal.core.schedule import CameraLimits, Schedule
from lrm.agent import Agent, AgentConfig
from lrm.camera import SimulatedCamera, SimulatedSensors
from lrm.clock import SimClock
from lrm.dive import DiveSimulation
from lrm.runner import LemTimetableClock, ScheduleRunner


def simulated_module(
    sim: DiveSimulation,
    config: AgentConfig,
    clock: SimClock,
    schedule: Schedule,
    *,
    readout_s: float = 0.8,
    lem_settle_s: float = 0.0,
    clock_error_s: float = 0.0,
) -> Agent:
    """The agent of module ``config.module`` of a simulated dive (not started).

    It takes pictures only while the dive's profile allows (not on deck),
    waits ``lem_settle_s`` after each change of LEM colour, and refuses
    schedules its camera cannot take (the camera's limits). ``clock_error_s``: its clock that far
    off (what it stamps and sends; see `lrm.agent.Agent`).
    """
    module = config.module
    if module not in sim.module_ids:
        raise ValueError(f"module must be one of {', '.join(sim.module_ids)}, got {module!r}")
    cam = SimulatedCamera(sim, module, clock, readout_s=readout_s)
    runner = ScheduleRunner(
        cam,
        clock,
        schedule,
        lem=LemTimetableClock(sim.timetable, sim.start, settle_s=lem_settle_s),
        gate=lambda: sim.profile.captures_enabled(sim.dive_time_s(clock.now())),
    )
    return Agent(
        config,
        clock=clock,
        runner=runner,
        sensors=SimulatedSensors(sim, module, clock),
        camera_limits=CameraLimits(cam.exposure_range_s, cam.gain_range_db, cam.gain_step_db),
        simulated_clock_error_s=clock_error_s,
    )
