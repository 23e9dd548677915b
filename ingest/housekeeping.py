"""The store thread's once-a-second work and module bookkeeping.

Links and module state, attitude from the sensor samples, alarms (raised
once, changed when their state changes, cleared when the condition ends),
disk and retention, operator commands (delivered oldest first, repeated
until the module answers; a status counts only from the command's own
module), the credit window, and the counters (saved once a second and with
every commit, so a restart continues them; `ingest.storeloop` saves and
publishes them).
"""

from __future__ import annotations

import logging
import shutil
import time
from collections import defaultdict
from typing import Any

from pydantic import ValidationError

from analysis.attitude import attitude_from_samples
from camcal.core import wire
from camcal.core.events import EventKind
from ingest.context import StoreContext
from ingest.gaps import Gaps
from ingest.messages import Note
from ingest.sensorbuf import SensorBuffers
from storage import queries

log = logging.getLogger("camcal.ingest")

#: Seconds of sensor samples the attitude (tilt, rotation, heave period) is estimated from.
ATTITUDE_WINDOW_S = 120.0
#: A module clock's offset is stored again after it moved, at most this often [s].
CLOCK_KEEP_S = 10.0
#: Commands of one module sent in one round of the store thread, at most (oldest first).
COMMANDS_PER_TICK = 16


class Housekeeping:
    def __init__(self, ctx: StoreContext, gaps: Gaps, sensors: SensorBuffers) -> None:
        self.st = ctx
        self.store = ctx.store
        self.gaps = gaps
        self.sensors = sensors
        cfg = ctx.config
        self.active_alarms = {
            a.key
            for a in self.store.call(queries.active_alarms)
            if a.module_id is None or cfg.serves(a.module_id)
        }
        self.attitude_t: dict[str, float] = {}
        #: Per module, the clock stored last: (boot, offset, when).
        self.clocks_kept: dict[str, tuple[str, float, float]] = {}
        self.last_housekeeping = -1e18
        self.last_purge = -1e18

    # -- links and modules ----------------------------------------------
    def link(self, it: Note) -> None:
        info = it.info or {}
        self.st.events.emit(
            EventKind.LINK,
            {"state": "up" if info["up"] else "down", "reason": info.get("reason")},
            module=it.module,
            dive_id=self.st.dive_id,
        )
        if not info["up"] and info.get("boot") and info.get("last_seq"):
            self.gaps.link_down(it.module, info["boot"], int(info["last_seq"]))

    def module_info(self, it: Note) -> None:
        m = it.msg
        sched = m.schedule
        cameras = self.st.config.setup.cameras
        self.store.touch_module(
            m.module,
            seen_unix_s=it.received_unix_s,
            boot=m.boot,
            software=getattr(m, "software", None) or None,
            schedule_name=sched.name,
            schedule_version=sched.version,
            schedule_state=sched.state,
            distance_m=cameras[m.module].distance_m if m.module in cameras else None,
            camera_json=m.camera.model_dump_json() if getattr(m, "camera", None) is not None else None,
        )

    # -- commands --------------------------------------------------------
    def command_status(self, it: Note) -> None:
        m = it.msg
        cmd = self.store.call(queries.command, m.command_id)
        if cmd is None or cmd["module"] != m.module:
            self.st.acknowledge.refuse(
                m,
                "invalid_field",
                f"command_status: no command {m.command_id!r} was sent to module {m.module}",
            )
            return
        cmd = self.store.update_command(m.command_id, m.state, m.reason, actor=f"module:{m.module}")
        self.module_info(it)
        if cmd is not None:
            self.st.events.emit(
                EventKind.COMMAND,
                {
                    "command_id": cmd["id"],
                    "state": cmd["state"],
                    "reason": cmd["reason"],
                    "action": cmd["action"],
                    "target_version": cmd["target_version"],
                },
                module=m.module,
                dive_id=self.st.dive_id,
            )

    def deliver_commands(self) -> None:
        """Send queued commands to linked modules, oldest first; repeat until the module answers.

        Oldest first: commands queued while a module was offline (pause, then
        resume) must reach it in the order the operator issued them; at most
        `COMMANDS_PER_TICK` of a module a round. A command that cannot be put on
        the wire is refused by the ship, saying why: before, one such command
        (a schedule version past the largest) failed every round and held up
        every command after it.
        """
        st = self.st
        now = time.time()
        links = st.links
        for cmd in self.store.call(queries.commands_to_deliver, COMMANDS_PER_TICK):
            link = links.get(cmd["module"])
            if link is None or not link.up:
                continue  # stays pending: delivered when the module is back
            if cmd["state"] == "accepted" or (
                cmd["attempts"] and now - cmd["updated_unix_s"] < st.config.command_retry_s
            ):
                continue
            try:
                msg = wire.Command(
                    module="ship",
                    command_id=cmd["id"],
                    action=cmd["action"],
                    target_version=cmd["target_version"],
                    schedule=(cmd["payload"] or {}).get("schedule"),
                    apply=cmd["apply"],
                    issued_by=cmd["issued_by"],
                )
            except ValidationError as exc:
                e = exc.errors()[0]
                why = f"the ship cannot send it ({'.'.join(map(str, e['loc']))}: {e['msg']})"
                if self.store.update_command(cmd["id"], "rejected", why, actor="ship") is not None:
                    self._command_event(cmd, "rejected", why)
                continue
            st.acknowledge.send(cmd["module"], msg)
            self.store.mark_command_sent(cmd["id"])
            if not cmd["attempts"]:
                self._command_event(cmd, "sent")

    def _command_event(self, cmd: dict[str, Any], state: str, reason: str | None = None) -> None:
        self.st.events.emit(
            EventKind.COMMAND,
            {
                "command_id": cmd["id"],
                "state": state,
                **({"reason": reason} if reason else {}),
                "action": cmd["action"],
                "target_version": cmd["target_version"],
            },
            module=cmd["module"],
            dive_id=self.st.dive_id,
        )

    # -- once a second ---------------------------------------------------
    def tick(self) -> None:
        """Each step guarded apart: one that fails is logged and the others still run."""
        g = self.st.guarded
        now, mono = time.time(), time.monotonic()
        g("attitude", self._attitude)
        g("link alarms", self._observe_links, mono)
        g("gap alarms", self._observe_gaps)
        if mono - self.last_housekeeping >= 30.0:
            self.last_housekeeping = mono
            g("disk", self._disk, now)
        crashes = list(self.st.analysis.crashes)
        g("analysis crashes", self.st.alarms.observe_analysis_crashes, crashes)
        g("alarms", self._apply_alarms, self.st.alarms.evaluate(now))
        g("commands", self.deliver_commands)
        g("window", lambda: self.st.credit.adapt(self.st.backlog()))

    def publish_health(self, counts: dict[str, dict[str, int]] | None = None) -> None:
        self.st.events.transient(EventKind.HEALTH, self.st.health(counts))

    def save_counters(self, counts: dict[str, dict[str, int]] | None = None) -> None:
        """Save the counters (``counts``, a snapshot; default: now) if any changed since the last save."""
        if self.st.counters.flat_if_changed() is not None:
            values = self.st.counters.flat(counts or self.st.counters.snapshot())
            self.store.save_counters(self.st.ingest_id, values)

    def _attitude(self) -> None:
        st = self.st
        rows = []
        for module, buf in self.sensors.sensors.items():
            if len(buf) < 5 or self.attitude_t.get(module) == buf[-1][0]:
                continue  # too few samples, or none new since the last tick
            self.attitude_t[module] = buf[-1][0]
            recent = self.sensors.tail(module, ATTITUDE_WINDOW_S)
            est = attitude_from_samples(recent[:, 0], recent[:, 1:4], recent[:, 4:7])
            self.st.alarms.observe_tilt(module, est.tilt_deg)
            row = {
                "module_id": module,
                "dive_id": st.dive_id,
                "t_unix_s": float(recent[-1, 0]),
                "t_ship_unix_s": link.clock_map().ship(float(recent[-1, 0]))
                if (link := st.links.get(module)) is not None
                else None,
                "tilt_deg": est.tilt_deg,
                "tilt_x_deg": est.tilt_x_deg,
                "tilt_y_deg": est.tilt_y_deg,
                "rotation_rate_dps": est.rotation_rate_dps,
                "heave_period_s": est.heave_period_s,
                "heave_amplitude_m_s2": est.heave_amplitude_m_s2,
            }
            rows.append(row)
            st.events.transient(
                EventKind.ATTITUDE, {k: v for k, v in row.items() if k != "module_id"}, module=module
            )
        self.store.add_attitude(rows)

    def _observe_links(self, mono: float) -> None:
        st = self.st
        for link in list(st.links.values()):
            age_up = link.up and mono - link.last_seen_mono <= st.config.link_timeout_s
            self.st.alarms.observe_link(
                link.module, age_up, link.last_seen_unix_s or None, signed_off=link.down_reason == "bye"
            )
            alarms = self.st.alarms
            alarms.observe_failures("card", link.module, link.boot, link.card_skipped, link.card_error)
            alarms.observe_failures("camera", link.module, link.boot, link.capture_errors, link.camera_error)
            alarms.observe_failures("sensors", link.module, link.boot, link.sensor_errors, link.sensor_error)
            alarms.observe_clock(link.module, link.clock_offset_s)
            self._keep_clock(link)
            if age_up:
                alarms.observe_production(
                    link.module,
                    link.schedule,
                    link.waiting,
                    link.last_frame_unix_s,
                    link.outbox_pending,
                    time.time(),
                )

    def _keep_clock(self, link: Any) -> None:
        """Store a module's clock as mapped now (`camcal.core.clockmap`): at a new boot at once, then
        when its offset moved (at most every `CLOCK_KEEP_S`), so that the dive keeps how each of its
        module times relates to the ship's."""
        if not link.clock_boot or not link.clock_readings:
            return
        clock, n, now = link.clock_map(), len(link.clock_readings), time.time()
        kept = self.clocks_kept.get(link.module)
        if (
            kept is not None
            and kept[0] == link.clock_boot
            and (abs(kept[1] - clock.offset_s) < 0.01 or now - kept[2] < CLOCK_KEEP_S)
        ):
            return
        self.store.record_module_clock(self.st.dive_id, link.module, link.clock_boot, clock, n, now)
        self.clocks_kept[link.module] = (link.clock_boot, clock.offset_s, now)

    def _observe_gaps(self) -> None:
        st = self.st
        gaps: dict[str, list[tuple[int, int, float]]] = defaultdict(list)
        for g in self.store.call(queries.open_gaps):  # one query for every module, not one per module
            if st.config.serves(g.module_id):
                gaps[g.module_id].append((g.first_seq, g.last_seq, g.detected_unix_s))
        links = st.links
        for module in set(gaps) | set(links):
            self.st.alarms.observe_gaps(module, gaps.get(module, []))

    def _disk(self, now: float) -> None:
        """Free disk (an alarm when it runs low) and, hourly, the retention of old frame files."""
        st = self.st
        free_gb = shutil.disk_usage(st.store.files.root).free / 1e9
        st.disk_free_gb = round(free_gb, 2)
        self.st.alarms.observe_disk(free_gb)
        days = st.config.retention_days
        if days and time.monotonic() - self.last_purge >= 3600.0:
            self.last_purge = time.monotonic()
            n, freed = self.store.purge_frame_files(now - days * 86400.0, st.config.modules)
            if n:
                log.info(
                    "retention: deleted %d frame files older than %g days (%.1f MB)", n, days, freed / 1e6
                )
                st.events.emit(
                    EventKind.RETENTION,
                    {"files": n, "bytes": freed, "older_than_days": days},
                    dive_id=st.dive_id,
                )

    def _apply_alarms(self, conditions: dict[str, Any]) -> None:
        st = self.st
        for key, c in conditions.items():
            alarm, changed = self.store.raise_alarm(key, c.kind, c.severity, c.message, c.module)
            if changed or key not in self.active_alarms:
                st.events.emit(
                    EventKind.ALARM,
                    {
                        "alarm_id": alarm.id,
                        "state": "raised",
                        "kind": c.kind,
                        "severity": c.severity,
                        "message": c.message,
                    },
                    module=c.module,
                    dive_id=st.dive_id,
                )
            self.active_alarms.add(key)
        for key in list(self.active_alarms - set(conditions)):
            cleared = self.store.clear_alarm(key)
            self.active_alarms.discard(key)
            if cleared is not None:
                st.events.emit(
                    EventKind.ALARM,
                    {
                        "alarm_id": cleared.id,
                        "state": "cleared",
                        "kind": cleared.kind,
                        "severity": cleared.severity,
                        "message": cleared.message,
                    },
                    module=cleared.module_id,
                    dive_id=st.dive_id,
                )
