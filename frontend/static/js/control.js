// The control page: a module's schedule and commands. Pick a module, start from its current schedule
// or a preset, edit, preview one pass, confirm, send; follow the command live until the module answers.
//
// Everything disruptive goes through a confirmation that says what will happen; the server judges the
// schedule (its messages appear at their fields); watching needs no login, acting needs the operator's.

import { ApiError, api, operator } from "./api.js";
import { FINAL, applyText, renderCommands, renderTracker } from "./control-commands.js";
import { ScheduleEditor } from "./control-editor.js";
import { VERDICTS, fmtDuration, renderPreview } from "./control-preview.js";
import { currentSpec, mismatchText, scheduleSources } from "./control-sources.js";
import { renderPermissions, renderStatus, renderTabs } from "./control-status.js";
import { plural } from "./format.js";
import { LiveSocket } from "./livesocket.js";
import { $, confirmDialog, initTheme, lrm, mountOperator, setText, showSimulation, toast } from "./ui.js";

const RECENT_FRAMES = 8;
const PREVIEW_DELAY_MS = 350;
// The preview judges settings from the frames analysed so far: new results refresh it, at most this often.
const PREVIEW_REFRESH_MS = 5000;
const POLL_MS = 4000;
const RANK = { pending: 0, sent: 1, accepted: 2, in_progress: 3, done: 4, rejected: 4 };
const state = {
  conn: "connecting",
  modules: new Map(),
  selected: null,
  presets: {},
  commands: new Map(), // module -> [command], newest first
  followed: null, // id of the command this page follows
  loadedFrom: null, // "current", "preset:NAME" or "cmd:ID"
  dirty: false,
  preview: null,
  previewError: null,
  sent: null, // {module, key, command}: the schedule just sent; Send stays off until the form changes
};
window.camcalControl = state;

let editor;
let previewTimer = null;
let previewAbort = null;
let lastPreviewAt = 0;

// ------------------------------------------------------------------ modules
function moduleState(id) {
  let m = state.modules.get(id);
  if (!m) {
    m = { id, link: "unknown", schedule: null, distance_m: null, recent: [] };
    state.modules.set(id, m);
  }
  return m;
}

function pushFrame(m, f) {
  if (!f || m.recent.some((r) => r.key === `${f.boot}|${f.seq}`)) return;
  m.recent.unshift({ ...f, key: `${f.boot}|${f.seq}` });
  m.recent.sort((a, b) => b.captured_unix_s - a.captured_unix_s);
  m.recent.length = Math.min(m.recent.length, RECENT_FRAMES);
}

function onSnapshot(d) {
  showSimulation(d.simulation_speed);
  for (const [id, sm] of Object.entries(d.modules || {})) {
    const m = moduleState(id);
    Object.assign(m, { link: sm.link, schedule: sm.schedule, distance_m: sm.distance_m, deferred_shots: sm.deferred_shots });
    pushFrame(m, sm.latest_frame);
  }
  if (!state.selected || !state.modules.has(state.selected)) pickModule();
  // events may have been missed while the socket was down; every module's commands tell what it runs
  for (const id of state.modules.keys()) loadCommands(id);
  render();
}

/** The module named in the address (#module=A), else the first one known. */
function pickModule() {
  const want = new URLSearchParams(location.hash.slice(1)).get("module");
  const ids = [...state.modules.keys()].sort();
  if (ids.length) select(state.modules.has(want) ? want : ids[0]);
}

function onEvent(msg) {
  const p = msg.payload || {};
  if (msg.kind === "health") {
    for (const [id, h] of Object.entries(p.modules || {})) {
      const m = moduleState(id);
      const before = JSON.stringify(m.schedule);
      Object.assign(m, { link: h.link, schedule: reported(m, h.schedule), deferred_shots: h.deferred_shots });
      if (id === state.selected && before !== JSON.stringify(h.schedule)) startOptions();
    }
    if (!state.selected) pickModule();
  } else if (msg.kind === "link" && msg.module) {
    moduleState(msg.module).link = p.state;
  } else if (msg.kind === "frame" && msg.module) {
    pushFrame(moduleState(msg.module), p);
  } else if (msg.kind === "result") {
    if (Date.now() - lastPreviewAt >= PREVIEW_REFRESH_MS) schedulePreview();
    return;
  } else if (msg.kind === "command" && msg.module) {
    const list = state.commands.get(msg.module);
    const c = list?.find((x) => x.id === p.command_id);
    if (c) upsert({ ...c, state: p.state, reason: p.reason ?? c.reason });
    else if (msg.module === state.selected) loadCommands(msg.module);
  } else {
    return;
  }
  render();
}

// ------------------------------------------------------------------ what a module runs
const ACTION_STATE = { start: "running", pause: "paused", resume: "running", stop: "stopped" };
const DONE_HOLD_MS = 20000;

/**
 * A command the module reported done changes what the page shows at once: the new schedule's name and
 * version, the state an action leads to. The module's heartbeat says the same a few seconds later;
 * until it does (or DONE_HOLD_MS pass), an older heartbeat does not take it back.
 */
function applyDone(c) {
  const m = state.modules.get(c.module);
  if (!m || c.state !== "done") return;
  if (c.action === "set_schedule" && c.payload?.schedule) {
    if ((m.schedule?.version ?? 0) >= c.target_version && m.schedule?.name === c.payload.schedule.name) return;
    m.schedule = { ...(m.schedule || { state: "running" }), name: c.payload.schedule.name, version: c.target_version };
  } else if (ACTION_STATE[c.action] && m.schedule) {
    if (m.doneAt?.id === c.id) return;
    m.schedule = { ...m.schedule, state: ACTION_STATE[c.action] };
  } else {
    return;
  }
  m.doneAt = { id: c.id, at: Date.now(), schedule: m.schedule };
  if (c.module === state.selected) startOptions();
}

/** The schedule a heartbeat reports, unless it is older than a command the module said is done. */
function reported(m, sch) {
  const held = m.doneAt;
  if (!held || !sch || Date.now() - held.at > DONE_HOLD_MS) return sch;
  const mine = held.schedule;
  if (sch.version > mine.version || (sch.version === mine.version && sch.state === mine.state)) {
    m.doneAt = null; // the heartbeat caught up
    return sch;
  }
  return { ...sch, name: mine.name, version: mine.version, state: mine.state };
}

/** Whether the modules' schedules differ in their settings (`mismatchText`); `instead` puts a schedule
 * about to be sent in place of one module's. */
function mismatch(instead = null) {
  const specs = [...state.modules.values()]
    .sort((a, b) => a.id.localeCompare(b.id))
    .map((m) =>
      instead?.module === m.id
        ? { id: m.id, schedule: { name: instead.spec.name, version: instead.version }, spec: instead.spec }
        : { id: m.id, schedule: m.schedule, spec: currentSpec(m, state.commands.get(m.id) || [], state.presets) },
    );
  return mismatchText(specs);
}

function select(id) {
  state.selected = id;
  history.replaceState(null, "", `#module=${encodeURIComponent(id)}`);
  state.followed = (state.commands.get(id) || [])[0]?.id ?? null;
  loadCommands(id);
  loadRecentFrames(id);
  render();
  schedulePreview(0);
}

/** The module's newest frames from the API (the snapshot holds only the latest one). */
async function loadRecentFrames(id) {
  try {
    const page = await api(`/api/frames?module=${encodeURIComponent(id)}&order=newest&limit=${RECENT_FRAMES}`);
    const m = moduleState(id);
    for (const f of page.items) pushFrame(m, f);
    render();
  } catch {
    /* the live frame events fill the list anyway */
  }
}

// ------------------------------------------------------------------ commands
async function loadCommands(id) {
  try {
    const list = await api(`/api/modules/${encodeURIComponent(id)}/commands?limit=50`);
    const known = new Map((state.commands.get(id) || []).map((c) => [c.id, c]));
    state.commands.set(
      id,
      list.map((c) => (known.has(c.id) && RANK[known.get(c.id).state] > RANK[c.state] ? known.get(c.id) : c)),
    );
    if (id === state.selected && !state.followed) state.followed = list[0]?.id ?? null;
  } catch (err) {
    toast(err.message);
    return;
  }
  if (id === state.selected) {
    startOptions();
    render();
  }
}

/** Add or update a command, never moving its state backwards (an event may beat the POST's answer). */
function upsert(c) {
  const list = state.commands.get(c.module) || [];
  const i = list.findIndex((x) => x.id === c.id);
  if (i < 0) list.unshift(c);
  else if (RANK[c.state] >= RANK[list[i].state]) list[i] = { ...list[i], ...c };
  state.commands.set(c.module, list);
  applyDone(list[i < 0 ? 0 : i]);
}

function followedCommand() {
  for (const list of state.commands.values()) {
    const c = list.find((x) => x.id === state.followed);
    if (c) return c;
  }
  return null;
}

/** The next version the server will accept for a module: above what it runs and what it was sent. */
function nextVersion(m) {
  let v = m.schedule?.version || 0;
  for (const c of state.commands.get(m.id) || []) {
    if (c.action === "set_schedule" && c.state !== "rejected") v = Math.max(v, c.target_version);
  }
  return v + 1;
}

// ------------------------------------------------------------------ where a schedule starts from
function sources() {
  const m = state.modules.get(state.selected);
  return m ? scheduleSources(m, state.commands.get(m.id) || [], state.presets) : null;
}

function startOptions() {
  const src = sources();
  if (!src || !editor) return;
  editor.setStartOptions(src.groups, state.loadedFrom);
  if (!state.loadedFrom || (!state.dirty && state.loadedFrom === "current")) {
    loadFrom(src.byValue.has("current") ? "current" : "preset:trex-subsampled");
  }
}

function loadFrom(value) {
  const src = sources()?.byValue.get(value);
  if (!src) return;
  state.loadedFrom = value;
  state.dirty = false;
  editor.fill(src.spec);
  $("#start-from").value = value;
  state.startNote = src.note;
  setText($("#start-note"), src.note);
  schedulePreview(0);
}

// ------------------------------------------------------------------ preview
function schedulePreview(delay = PREVIEW_DELAY_MS) {
  clearTimeout(previewTimer);
  previewTimer = setTimeout(() => runPreview().catch(() => {}), delay);
}

/** Ask the server to check and preview the form's schedule; returns {ok, problems} or throws on a network error. */
async function runPreview() {
  if (!editor || !state.selected || !state.loadedFrom) return null;
  previewAbort?.abort();
  const ctrl = new AbortController();
  previewAbort = ctrl;
  const spec = editor.read();
  lastPreviewAt = Date.now();
  try {
    // checked against the selected module's own camera, where it has said its ranges (predictions for every module)
    const p = await api("/api/schedules/preview", { method: "POST", body: { schedule: spec, camera_of: state.selected }, signal: ctrl.signal });
    if (ctrl.signal.aborted) return null;
    state.preview = p;
    state.previewError = null;
    editor.showProblems(p.problems);
    renderPreviewBox();
    return { ok: p.ok, problems: p.problems, preview: p };
  } catch (err) {
    if (err.name === "AbortError") return null;
    if (err instanceof ApiError && err.status === 422) {
      state.preview = null;
      state.previewError = "The server cannot take this schedule: see the fields marked in red.";
      editor.showProblems(err.detail || [{ field: "schedule", reason: err.message }]);
      renderPreviewBox();
      return { ok: false, problems: err.detail || [] };
    }
    state.previewError = err.message;
    renderPreviewBox();
    // The server computes a few previews at once and refuses the next (503, a second later): ask again.
    if (err instanceof ApiError && err.status === 503) schedulePreview(1500);
    throw err;
  }
}

function renderPreviewBox() {
  const ids = [...state.modules.keys()].sort((a, b) => (a === state.selected ? -1 : b === state.selected ? 1 : a.localeCompare(b)));
  renderPreview($("#preview"), state.preview, { modules: ids, selected: state.selected, error: state.previewError });
}

// ------------------------------------------------------------------ sending
function offlineNote(m) {
  return m.link === "up" ? null : `${lrm(m.id)} is offline (link ${m.link}): the command waits, pending, until it reconnects.`;
}

async function sendSchedule(ev) {
  ev.preventDefault();
  const m = state.modules.get(state.selected);
  const note = $("#send-note");
  if (!m || !operator()) return;
  const spec = editor.read();
  const apply = editor.apply();
  clearTimeout(previewTimer); // a pending preview of an earlier edit must not cancel this check
  let checked;
  try {
    checked = await runPreview();
  } catch (err) {
    setText(note, `Not sent: ${err.message}`);
    return;
  }
  if (!checked) {
    setText(note, "Not sent: the schedule changed while it was being checked; send again.");
    return;
  }
  if (!checked.ok) {
    setText(note, "Not sent: fix the fields marked in red.");
    editor.form.querySelector(".invalid input, .invalid select")?.focus();
    return;
  }
  const p = checked.preview;
  const version = nextVersion(m);
  const from = m.schedule ? `from ${m.schedule.name} v${m.schedule.version} ` : "";
  const counts = p.summary?.[m.id];
  const judged = counts
    ? Object.keys(VERDICTS)
        .filter((k) => counts[k])
        .map((k) => `${counts[k]} ${VERDICTS[k]}`)
        .join(", ")
    : "no frames of this module to judge from yet";
  const ok = await confirmDialog({
    title: `Send a schedule to ${lrm(m.id)}?`,
    message: `Module ${m.id} will switch ${from}to ${spec.name} v${version} ${applyText(apply)}.`,
    details: [
      `One pass: ${plural(p.n_frames, "frame")}, about ${fmtDuration(p.pass_duration_s)}.`,
      ...(p.warnings || []).map((w) => `Note: ${w}.`),
      `Settings predicted for ${lrm(m.id)}: ${judged}.`,
      `Its frames will carry schedule version ${version}.`,
      offlineNote(m),
      ((w) => (w ? `Warning: then ${w}` : null))(mismatch({ module: m.id, spec, version })),
    ].filter(Boolean),
    okLabel: `Send ${spec.name} v${version} to ${m.id}`,
  });
  if (!ok) {
    setText(note, "Not sent.");
    return;
  }
  setText(note, "sending…");
  try {
    const cmd = await api(`/api/modules/${encodeURIComponent(m.id)}/schedule`, {
      method: "POST",
      body: { schedule: spec, apply, version },
    });
    state.sent = { module: m.id, key: formKey(), command: cmd.id };
    follow(cmd);
    setText(note, `Sent as command #${cmd.id.slice(0, 8)}: change the schedule to send another.`);
    // what the editor holds is now what was sent, whatever it was started from
    state.startNote = `${spec.name} v${version}, as sent to ${lrm(m.id)} (command #${cmd.id.slice(0, 8)}).`;
    setText($("#start-note"), `Sent: ${state.startNote}`);
  } catch (err) {
    if (err instanceof ApiError && err.status === 422) {
      editor.showProblems(err.detail || [{ field: "schedule", reason: err.message }]);
      setText(note, "Not sent: fix the fields marked in red.");
    } else {
      setText(note, `Not sent: ${err.message}`);
      if (err instanceof ApiError && err.status === 409) loadCommands(m.id);
    }
  }
}

const ACTION_CONFIRM = {
  pause: (m, s) => ({
    title: `Pause ${lrm(m.id)}?`,
    message: `Module ${m.id} will pause ${s} after the frame it is taking: no frames until you resume it.`,
    okLabel: `Pause ${m.id}`,
  }),
  stop: (m, s) => ({
    title: `Stop ${lrm(m.id)}?`,
    message: `Module ${m.id} will stop ${s}: no frames until you start it again, and Start begins the pass from its first setting.`,
    okLabel: `Stop ${m.id}`,
    danger: true,
  }),
};

async function sendAction(action) {
  const m = state.modules.get(state.selected);
  if (!m || !operator()) return;
  const ask = ACTION_CONFIRM[action];
  if (ask) {
    const s = m.schedule ? `${m.schedule.name} v${m.schedule.version}` : "its schedule";
    const q = ask(m, s);
    if (!(await confirmDialog({ ...q, details: [offlineNote(m)].filter(Boolean) }))) return;
  }
  setText($("#send-note"), "");
  try {
    follow(await api(`/api/modules/${encodeURIComponent(m.id)}/commands`, { method: "POST", body: { action } }));
  } catch (err) {
    toast(err.message);
  }
}

/** What the Send button would send now (the schedule and when to apply it). */
function formKey() {
  return editor ? JSON.stringify([editor.read(), editor.apply()]) : "";
}

/** The command just sent, while the form still holds what it sent (and the module did not reject it). */
function justSent(m) {
  const s = state.sent;
  if (!m || !s || s.module !== m.id || s.key !== formKey()) return null;
  const c = (state.commands.get(m.id) || []).find((x) => x.id === s.command);
  return c && c.state === "rejected" ? null : s;
}

function follow(cmd) {
  upsert(cmd);
  state.followed = cmd.id;
  render();
  startOptions();
}

/** A command the page follows is also read back now and then: a missed event never leaves it stuck. */
async function poll() {
  const c = followedCommand();
  if (c && !FINAL.has(c.state)) {
    try {
      upsert(await api(`/api/commands/${c.id}`));
      render();
    } catch {
      /* the next poll or event will tell */
    }
  }
}

// ------------------------------------------------------------------ rendering
function render() {
  setText($("#conn"), state.conn === "live" ? "live" : state.conn === "connecting" ? "connecting…" : "reconnecting…");
  $("#conn").dataset.state = state.conn;
  const banner = $("#banner");
  banner.hidden = state.conn === "live" || state.conn === "connecting";
  setText(banner, banner.hidden ? "" : "Connection to the ship server lost — reconnecting. Module states and commands below may be out of date.");
  renderTabs($("#module-tabs"), state.modules, state.selected, select);
  const m = state.modules.get(state.selected);
  renderStatus($("#module-status"), $("#recent-frames"), m, mismatch());
  renderPermissions(m, operator(), justSent(m));
  const c = followedCommand();
  renderTracker($("#tracker"), c, c ? state.modules.get(c.module) : null);
  renderCommands($("#commands-table"), state.commands.get(state.selected) || [], state.followed);
}

// ------------------------------------------------------------------ start
async function init() {
  initTheme($("#theme"));
  mountOperator($("#operator"));
  window.addEventListener("camcal:auth", () => render());
  editor = new ScheduleEditor($("#schedule-form"), {
    onChange: () => {
      state.dirty = true;
      if (state.startNote) setText($("#start-note"), `Edited. Started from: ${state.startNote}`);
      setText($("#send-note"), "");
      schedulePreview();
      render(); // the Send button comes back once the form differs from what was sent
    },
  });
  $("#start-from").addEventListener("change", (ev) => {
    loadFrom(ev.target.value);
    render();
  });
  $("#schedule-form").addEventListener("submit", sendSchedule);
  for (const b of document.querySelectorAll("#actions [data-action]")) {
    b.dataset.title = b.title;
    b.addEventListener("click", () => sendAction(b.dataset.action));
  }
  renderPreviewBox();
  render();
  try {
    state.presets = await api("/api/schedules/presets");
  } catch (err) {
    toast(err.message);
  }
  new LiveSocket({
    onSnapshot,
    onEvent,
    onState: (s) => {
      state.conn = s;
      render();
    },
  }).start();
  setInterval(poll, POLL_MS);
}

init();
