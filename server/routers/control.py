"""Schedules and commands: presets, validation and preview, and sending them to modules."""

from __future__ import annotations

import csv
import functools
import io
import json
import uuid
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query
from fastapi.responses import Response
from pydantic import BaseModel, ConfigDict, Field

from camcal.core.numbers import Integer
from camcal.core.passplan import plan_pass
from camcal.core.schedule import CameraLimits, Schedule, presets
from camcal.core.utctime import iso_utc
from ingest.derived import predict_settings, result_row
from server.deps import ModuleId, OperatorDep, PreviewSlotDep, SettingsDep, StoreDep
from server.errors import Conflict, Invalid, NotFound
from server.openapi import BUSY, CONFLICT
from server.saturation import newest_results
from server.schemas import CommandPublic, PresetPublic, Preview
from storage import queries
from storage.store import Store

router = APIRouter(tags=["control"])


class ScheduleCommand(BaseModel):
    """A schedule for a module. ``version`` defaults to one above what the module runs or was sent."""

    model_config = ConfigDict(extra="forbid")
    schedule: Schedule
    apply: Literal["now", "end_of_setting"] = "now"
    version: Integer | None = Field(None, ge=1, le=2**31 - 1)


class ActionCommand(BaseModel):
    model_config = ConfigDict(extra="forbid")
    action: Literal["start", "pause", "resume", "stop"]


class PreviewRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")
    schedule: Schedule
    module: str | None = Field(None, max_length=64, description="predict for this module's frames only")
    camera_of: str | None = Field(
        None,
        max_length=64,
        description="check against this module's camera (default: ``module``'s; without either, or "
        "for a module that has not said its camera's ranges, the ship's default limits)",
    )


def camera_limits(settings: Any, store: Store, module: str | None) -> tuple[CameraLimits, str]:
    """The ranges a schedule for ``module`` must fit: its camera's, as the module said (protocol
    revision 1.8), else the ship's default limits (`ServerSettings.camera_limits`); and whose."""
    cam = store.call(queries.module_camera, module) if module else None
    if cam:
        try:
            limits = CameraLimits(
                (float(cam["exposure_range_s"][0]), float(cam["exposure_range_s"][1])),
                (float(cam["gain_range_db"][0]), float(cam["gain_range_db"][1])),
                float(cam.get("gain_step_db") or 0.0),
            )
            what = " ".join(str(cam.get(k) or "") for k in ("model", "serial")).strip() or "its camera"
            return limits, f"module {module}'s camera ({what})"
        except (KeyError, IndexError, TypeError, ValueError):
            pass  # (a row no module could have sent: the defaults)
    whose = f"module {module} has not said its camera's" if module else "no module chosen"
    return settings.camera_limits, f"the ship's default limits ({whose})"


def _problems(limits: CameraLimits, schedule: Schedule) -> list[dict[str, str]]:
    return [{"field": f"schedule.{f}", "reason": r} for f, r in limits.problems(schedule)]


#: The pass estimate of a schedule, by its content: the same schedule previewed again (every edit
#: of the form asks; every browser asks for the presets) is walked once.
_planned = functools.lru_cache(maxsize=128)(plan_pass)


def _pass_estimate(settings: Any, schedule: Schedule) -> dict[str, Any]:
    """One pass against the LEM's colour cycle (`camcal.core.passplan`): duration, busy share, warnings."""
    plan = _planned(schedule, settings.readout_s, settings.lem_dwell_s)
    return {
        "pass_duration_s": round(plan.duration_s, 1),
        "busy_share": round(plan.busy_share, 3),
        "turns_per_pass": {str(wl): round(n, 2) for wl, n in sorted(plan.turns.items())},
        "lem_dwell_s": plan.dwell_s,
        "warnings": plan.warnings(),
    }


@router.get("/api/schedules/presets", response_model=dict[str, PresetPublic])
def list_presets(settings: SettingsDep) -> dict[str, Any]:
    """The named schedules to start from: T-REX, quick λ_att check, linearity scan, monitoring.

    ``pass_duration_s`` and the rest are estimated as the preview does (the LEM's colour cycle walked).
    """
    return {
        name: {
            **s.model_dump(mode="json"),
            "n_frames": s.n_frames,
            **_pass_estimate(settings, s),
        }
        for name, s in presets().items()
    }


@router.post("/api/schedules/preview", response_model=Preview, responses=BUSY)
def preview(
    body: PreviewRequest, store: StoreDep, settings: SettingsDep, _slot: PreviewSlotDep
) -> dict[str, Any]:
    """Check a schedule and estimate one pass before sending it.

    Returns the problems (field and reason) the camera limits find, the
    frames and the duration of one pass against the LEM's colour cycle (the
    share of it the camera shoots, the LEM's turns of each colour it takes,
    and warnings: a wavelength's shots longer than the LEM shows a colour are
    spread over several turns), and per module and setting the
    centre gray expected from the frames seen so far (``ok``, ``too_dark``,
    ``saturated`` or ``unknown``).

    It needs no token (a watcher may plan a schedule too), so a few previews are computed at once
    (503 with ``Retry-After`` for the next), with slots of their own for operators
    (`server.jobs.PreviewSlots`); the pass estimate of a schedule previewed before is reused.
    """
    sched = body.schedule
    rr = [result_row(r) for r in store.call(newest_results, body.module)]
    setts = [(wl, e, g) for wl in sched.wavelengths_nm for e, g, _ in sched.settings()]
    pred = predict_settings(rr, setts, settings.linear_range) if rr else {}
    limits, source = camera_limits(settings, store, body.camera_of or body.module)
    problems = _problems(limits, sched)
    summary = {
        m: {v: sum(1 for p in ps if p["verdict"] == v) for v in ("ok", "too_dark", "saturated", "unknown")}
        for m, ps in pred.items()
    }
    estimate = _pass_estimate(settings, sched)
    estimate["warnings"] += _unusable_wavelengths(pred)
    return {
        "ok": not problems,
        "problems": problems,
        "camera_limits": {
            "exposure_range_s": limits.exposure_range_s,
            "gain_range_db": limits.gain_range_db,
            "gain_step_db": limits.gain_step_db,
            "source": source,
        },
        "n_frames": sched.n_frames,
        **estimate,
        "predictions": pred,
        "summary": summary,
    }


def _unusable_wavelengths(pred: dict[str, list[dict[str, Any]]]) -> list[str]:
    """A module for which no setting at a wavelength is predicted ok: no λ_att at it from that module."""
    out = []
    for module, ps in sorted(pred.items()):
        for wl in sorted({p["wavelength_nm"] for p in ps}):
            verdicts = [p["verdict"] for p in ps if p["wavelength_nm"] == wl]
            if "ok" in verdicts or "unknown" in verdicts:
                continue
            counts = ", ".join(
                f"{verdicts.count(v)} {v.replace('_', ' ')}"
                for v in ("saturated", "too_dark")
                if v in verdicts
            )
            out.append(
                f"no setting at {wl} nm is predicted usable for module {module} ({counts}): its frames "
                f"would give no λ_att at {wl} nm; change the exposures or gains"
            )
    return out


#: Commands of a module the ship delivers at once, at most: a burst beyond waits for the module's answers.
UNANSWERED_MAX = 32
#: How far past a module's schedule version a command may name its next one, and the largest version.
VERSION_STEP_MAX = 1000
VERSION_MAX = 2**31 - 1


def _not_swamped(store: Store, module_id: str) -> None:
    """409 while `UNANSWERED_MAX` commands of the module wait for its answer: thousands queued for a
    module (a burst of clicks, a script) held up its frames for minutes while the ship delivered them."""
    waiting = store.call(queries.commands_unanswered, module_id)
    if waiting >= UNANSWERED_MAX:
        raise Conflict(
            f"module {module_id} has {waiting} commands it has not answered yet (it is offline or busy): "
            f"wait for its answers (GET /api/modules/{module_id}/commands), then send again",
            {"unanswered": waiting},
        )


def _module_or_404(store: Store, module_id: str) -> None:
    if not store.call(queries.module_exists, module_id):
        raise NotFound(f"no module {module_id!r} has connected to this ship")


@router.post(
    "/api/modules/{module_id}/schedule", status_code=202, response_model=CommandPublic, responses={**CONFLICT}
)
def send_schedule(
    module_id: ModuleId, body: ScheduleCommand, store: StoreDep, settings: SettingsDep, who: OperatorDep
) -> dict[str, Any]:
    """Send a schedule to a module (operator token). Queued while the module is offline.

    The command names its target state, the schedule version N; the module
    applies it at most once and reports accepted / rejected / in progress /
    done, which ``GET /api/commands/{id}`` and the live events show.
    """
    _module_or_404(store, module_id)
    limits, source = camera_limits(settings, store, module_id)
    problems = _problems(limits, body.schedule)
    if problems:
        raise Invalid(f"{problems[0]['field']}: {problems[0]['reason']} (checked against {source})", problems)
    _not_swamped(store, module_id)
    current = store.call(queries.schedule_version, module_id)
    version = body.version if body.version is not None else current + 1
    if version <= current:
        raise Conflict(
            f"schedule version {version} is not newer than version {current} of module {module_id}",
            {"current_version": current},
        )
    if version > current + VERSION_STEP_MAX or version > VERSION_MAX:
        # A version past the wire's largest could never be sent (and held up every command after it);
        # one at the largest would leave no newer version for the module's next schedule.
        raise Conflict(
            f"schedule version {version} jumps more than {VERSION_STEP_MAX} past version {current} of module "
            f"{module_id}"
            + (" (the largest there is)" if current + 1 > VERSION_MAX else "")
            + ": leave the version out (the next is the module's plus one)",
            {"current_version": current},
        )
    sched = Schedule.model_validate({**body.schedule.model_dump(), "version": version})
    return store.create_command(
        uuid.uuid4().hex,
        module_id,
        "set_schedule",
        who,
        payload={"schedule": sched.model_dump(mode="json")},
        target_version=version,
        apply=body.apply,
    )


@router.post("/api/modules/{module_id}/commands", status_code=202, response_model=CommandPublic)
def send_action(
    module_id: ModuleId, body: ActionCommand, store: StoreDep, who: OperatorDep
) -> dict[str, Any]:
    """Start, pause, resume or stop whatever schedule the module runs (operator token).

    The command targets version 0 ("the running schedule"): a pause sent while
    a new schedule waits for the end of a setting must pause the module, not
    be refused because the new version is not running yet.
    """
    _module_or_404(store, module_id)
    _not_swamped(store, module_id)
    return store.create_command(uuid.uuid4().hex, module_id, body.action, who, target_version=0)


@router.get("/api/modules/{module_id}/commands", response_model=list[CommandPublic])
def module_commands(
    module_id: ModuleId, store: StoreDep, limit: Annotated[int, Query(ge=1, le=1000)] = 50
) -> list[dict[str, Any]]:
    _module_or_404(store, module_id)
    return store.call(queries.commands, module_id, limit=limit)


@router.get("/api/commands", response_model=list[CommandPublic])
def all_commands(
    store: StoreDep,
    state: Annotated[
        Literal["pending", "sent", "accepted", "in_progress", "done", "rejected"] | None, Query()
    ] = None,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
) -> list[dict[str, Any]]:
    """Commands to any module, newest first; ``state`` keeps those in that state."""
    return store.call(queries.commands, states=(state,) if state else None, limit=limit)


@router.get("/api/commands/{command_id}", response_model=CommandPublic)
def get_command(command_id: Annotated[str, Path(max_length=64)], store: StoreDep) -> dict[str, Any]:
    cmd = store.call(queries.command, command_id)
    if cmd is None:
        raise NotFound(f"no command {command_id}")
    return cmd


@router.get("/api/audit/export", response_class=Response, responses={200: {"content": {"text/csv": {}}}})
def audit_export(store: StoreDep) -> Response:
    """The whole audit log as CSV."""
    rows = store.call(queries.audit, limit=1_000_000)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["id", "t_unix_s", "t_utc", "actor", "action", "target", "what", "details"])
    for r in reversed(rows):
        w.writerow(
            [r["id"], r["t_unix_s"], iso_utc(r["t_unix_s"]), r["actor"], r["action"], r["target"], r["what"],
             json.dumps(r["details"], ensure_ascii=False)]
        )  # fmt: skip
    return Response(
        buf.getvalue(),
        media_type="text/csv",
        headers={"Content-Disposition": 'attachment; filename="audit.csv"'},
    )
