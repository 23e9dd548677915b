// The live view: a snapshot, then events from WS /ws/live, drawn for a tablet on deck at night.
//
// Ages are measured on this browser's clock from when news arrived (never by comparing the
// ship's timestamps with ours), so a skewed tablet clock cannot make stale data look fresh.

import { api, operator } from "./api.js";
import { SEVERITY_RANK as RANK, fmtAge, qualityKey } from "./format.js";
import { createCard, showThumbnail, updateCard, updateQuality } from "./live-cards.js";
import { LiveSocket } from "./livesocket.js";
import { upsertVisit } from "./lambda-profile.js";
import { drawLambda, renderAlarms, renderLambdaNow, renderRefused } from "./live-panels.js";
import { $, initTheme, lrm, mountOperator, setText, showDiveState, showSimulation, toast } from "./ui.js";

const RECENT = 40; // ticks in a card's strip of latest frames
const PHASE_WINDOW_S = 30;
const THUMB_EVERY_MS = 500;
const DIVE_STATE_EVERY_MS = 10000; // how often the dive's state (open, ended and why) is read again
const ENDED_HINT = "The next start of camcal up begins a new dive; this one stays on the review page.";

const state = {
  dive: null,
  runId: null,
  staleAfter: 5,
  stationDepth: null,
  modules: new Map(),
  attenuation: {},
  alarms: new Map(),
  ingestUp: false,
  healthAt: null,
  refused: null, // the ingest's refused connections (unknown keys, plaintext): not modules, not alarms
  linkSecurity: null,
  conn: "connecting",
  connInfo: {},
  lastLiveAt: null,
  serverError: null, // what the server said it cannot do now (its database is down), until a snapshot
};

/** Figures for tests and bench/bench_dashboard.py. */
const stats = {
  snapshotAt: null,
  firstDataAt: null,
  firstThumbAt: null,
  thumbLatencyMs: [],
  events: 0,
  missed: {},
  snapshots: 0,
};
window.camcal = { state, stats };

const cards = new Map();
let attDirty = true;
let attDrawnAt = 0;
let renderQueued = false;

// ------------------------------------------------------------------ state from the server
function moduleState(mid) {
  let m = state.modules.get(mid);
  if (!m) {
    m = {
      id: mid,
      link: "unknown",
      lastPacketAt: null,
      lastFrameAt: null,
      frames_last_min: null,
      setting: null,
      shown: null,
      pending: null,
      loading: false,
      quality: {},
      recent: [],
      depthHist: [],
      maxDepth: 0,
      sensorsAt: null,
      thumbStartedAt: -Infinity,
    };
    state.modules.set(mid, m);
  }
  return m;
}

function onSnapshot(d) {
  const now = performance.now();
  stats.snapshots += 1;
  stats.snapshotAt ??= now;
  state.serverError = null;
  state.dive = d.dive;
  state.runId = d.run_id;
  state.staleAfter = d.stale_after_s ?? 5;
  state.stationDepth = d.station_depth_m ?? null;
  showSimulation(d.simulation_speed);
  state.ingestUp = Boolean(d.ingest?.up);
  state.healthAt = state.ingestUp ? now - (d.ingest.age_s || 0) * 1000 : null;
  state.refused = d.refused_connections || null;
  state.lastLiveAt = now;
  const seen = new Set();
  for (const [mid, sm] of Object.entries(d.modules || {})) {
    seen.add(mid);
    const m = moduleState(mid);
    Object.assign(m, {
      distance_m: sm.distance_m,
      link: sm.link,
      frames_per_s: sm.frames_per_s,
      frames_last_min: sm.frames_last_min,
      schedule: sm.schedule,
      sensors: sm.sensors,
      attitude: sm.attitude,
      phase: sm.phase,
      quality: { ...(sm.quality || {}) },
    });
    const age = sm.last_packet_age_s ?? (sm.last_seen_unix_s ? d.server_time_unix_s - sm.last_seen_unix_s : null);
    m.lastPacketAt = age === null ? null : now - age * 1000;
    m.lastFrameAt = sm.last_frame_age_s === null || sm.last_frame_age_s === undefined ? null : now - sm.last_frame_age_s * 1000;
    m.sensorsAt = sm.sensors ? m.lastPacketAt : null;
    m.maxDepth = Math.max(m.maxDepth, d.dive?.max_depth_m || 0);
    const lf = sm.latest_frame;
    if (lf) {
      m.setting ??= lf;
      if (!m.shown || m.shown.id !== lf.id) queueThumbnail(m, { ...lf, thumb: lf.thumbnail_url }, null);
    }
    if (sm.recent_outcomes?.length) m.recent = sm.recent_outcomes.slice(-RECENT); // the server's, after a reload
  }
  for (const mid of [...state.modules.keys()]) if (!seen.has(mid)) state.modules.delete(mid);
  state.attenuation = {};
  for (const [wl, pts] of Object.entries(d.attenuation || {})) state.attenuation[wl] = [...pts];
  state.alarms = new Map((d.alarms || []).map((a) => [a.id, a]));
  if (stats.firstDataAt === null && Object.keys(d.modules || {}).length) stats.firstDataAt = now;
  attDirty = true;
  render();
}

function queueThumbnail(m, frame, tEvent) {
  if (!frame.thumb) return;
  m.pending = { frame, tEvent };
  if (!m.loading) loadThumbnail(m);
}

/**
 * Load the newest waiting thumbnail off-screen, then swap it in: no half-drawn image, no flicker.
 * One at a time per module and at most one every THUMB_EVERY_MS: frames that come faster are
 * skipped (nobody reads more than two pictures a second), so twenty tablets cost the ship a
 * bounded number of requests however fast the modules send.
 */
function loadThumbnail(m) {
  const p = m.pending;
  if (!p || m.loading) return;
  const wait = m.thumbStartedAt + THUMB_EVERY_MS - performance.now();
  if (wait > 0) {
    m.loading = true;
    setTimeout(() => {
      m.loading = false;
      loadThumbnail(m);
    }, wait);
    return;
  }
  m.pending = null;
  m.loading = true;
  m.thumbStartedAt = performance.now();
  const img = new Image();
  img.decoding = "async";
  const done = (ok) => {
    m.loading = false;
    if (ok) {
      m.shown = p.frame;
      const card = cards.get(m.id);
      if (card) showThumbnail(card, img, p.frame);
      stats.firstThumbAt ??= performance.now();
      if (p.tEvent !== null) stats.thumbLatencyMs.push(performance.now() - p.tEvent);
      requestRender();
    }
    loadThumbnail(m);
  };
  img.onload = () => done(true);
  img.onerror = () => done(false);
  img.src = p.frame.thumb;
}

function onEvent(msg) {
  const now = performance.now();
  stats.events += 1;
  state.lastLiveAt = now;
  const p = msg.payload || {};
  const m = msg.module ? moduleState(msg.module) : null;
  switch (msg.kind) {
    case "health":
      state.ingestUp = true;
      state.healthAt = now;
      state.refused = p.refused_connections || null;
      state.linkSecurity = p.link_security || null;
      for (const [mid, h] of Object.entries(p.modules || {})) {
        const hm = moduleState(mid);
        hm.link = h.link;
        hm.frames_per_s = h.frames_per_s;
        hm.frames_last_min = h.frames_last_min;
        if (h.last_frame_age_s !== null && h.last_frame_age_s !== undefined) hm.lastFrameAt = now - h.last_frame_age_s * 1000;
        hm.schedule = h.schedule;
        // The ingest's own count is the truth; packets seen since (sensors, frames) refine it.
        if (h.last_packet_age_s !== null && h.last_packet_age_s !== undefined) {
          hm.lastPacketAt = now - h.last_packet_age_s * 1000;
        }
      }
      if (p.dive && (!state.dive || state.dive.id !== p.dive.id)) {
        state.dive = { ...p.dive };
        refreshDive(); // its state (open, ended and why) is the server's to say
      }
      break;
    case "sensors":
      m.sensors = p;
      m.sensorsAt = now;
      m.lastPacketAt = now;
      trackDepth(m, p);
      break;
    case "attitude":
      // Derived by the ingest (and repeated while a module is silent): not a packet.
      m.attitude = p;
      break;
    case "link":
      m.link = p.state;
      if (p.state === "up") m.lastPacketAt = now;
      break;
    case "frame":
      m.setting = p;
      m.lastPacketAt = now;
      m.lastFrameAt = now;
      break;
    case "result": {
      const frame = { ...p, id: p.frame_id };
      queueThumbnail(m, frame, now);
      const key = qualityKey(p);
      if (p.status !== "pending") {
        m.quality[key] = (m.quality[key] || 0) + 1;
        m.recent.push(key);
        if (m.recent.length > RECENT) m.recent.shift();
      }
      break;
    }
    case "attenuation": {
      // One point per LEM visit: a running visit's point is updated in place, final when it ends.
      if (upsertVisit(state.attenuation, p)) attDirty = true;
      break;
    }
    case "alarm":
      onAlarm(msg, p);
      break;
    default:
      break;
  }
  if (stats.firstDataAt === null && msg.module) stats.firstDataAt = now;
  requestRender();
}

function onAlarm(msg, p) {
  const id = p.alarm_id ?? p.id;
  const a = state.alarms.get(id) || { id, raised_unix_s: msg.t, acked_unix_s: null, acked_by: null };
  Object.assign(a, {
    kind: p.kind ?? a.kind,
    severity: p.severity ?? a.severity,
    message: p.message ?? a.message,
    module: msg.module ?? a.module,
  });
  if (p.state === "raised") {
    if (!a.active) a.raised_unix_s = msg.t;
    a.active = true;
    a.cleared_unix_s = null;
  } else if (p.state === "cleared") {
    a.active = false;
    a.cleared_unix_s = msg.t;
  } else if (p.state === "acked") {
    Object.assign(a, { acked_unix_s: p.acked_unix_s, acked_by: p.acked_by, active: p.active });
  }
  state.alarms.set(id, a);
}

/** The dive phase from the depth of the last ~30 s (as ingest.derived.dive_phase decides it). */
function trackDepth(m, s) {
  if (s.depth_m === null || s.depth_m === undefined || s.t_unix_s === undefined) return;
  m.depthHist.push([s.t_unix_s, s.depth_m]);
  m.maxDepth = Math.max(m.maxDepth, s.depth_m);
  const t1 = s.t_unix_s;
  while (m.depthHist.length && m.depthHist[0][0] < t1 - PHASE_WINDOW_S) m.depthHist.shift();
  const h = m.depthHist;
  if (s.depth_m < 5) {
    m.phase = "deck";
    return;
  }
  if (h.length < 3 || h[h.length - 1][0] <= h[0][0]) return;
  const n = h.length;
  const mt = h.reduce((a, x) => a + x[0], 0) / n;
  const md = h.reduce((a, x) => a + x[1], 0) / n;
  let num = 0;
  let den = 0;
  for (const [t, d] of h) {
    num += (t - mt) * (d - md);
    den += (t - mt) ** 2;
  }
  const rate = den ? num / den : 0;
  if (rate > 0.2) m.phase = "descent";
  else if (rate < -0.2) m.phase = "ascent";
  // With the dive plan a stop is the station only at its depth; without, the deepest stop so far is.
  else if (state.stationDepth !== null) m.phase = Math.abs(s.depth_m - state.stationDepth) <= 50 ? "station" : "stop";
  else m.phase = s.depth_m >= m.maxDepth - 50 ? "station" : "stop";
}

function onMissed(msg) {
  for (const [k, n] of Object.entries(msg.dropped || {})) stats.missed[k] = (stats.missed[k] || 0) + n;
}

function onServerError(msg) {
  state.serverError = msg.message || "the server cannot give the live state now";
  requestRender();
}

function onConn(s, info) {
  state.conn = s;
  state.connInfo = info;
  requestRender();
}

// ------------------------------------------------------------------ rendering
function requestRender() {
  if (renderQueued) return;
  renderQueued = true;
  requestAnimationFrame(() => {
    renderQueued = false;
    render();
  });
}

/** A module's state and why: [severity, reason in words or null]. */
function moduleSeverity(m, now) {
  let sev = "OK";
  let why = null;
  for (const a of state.alarms.values()) {
    if (!a.active || a.module !== m.id) continue;
    if (a.kind === "signed_off") return ["INFO", `${lrm(m.id)} signed off`]; // switched off on purpose, not stale
    if (RANK[a.severity] > RANK[sev]) [sev, why] = [a.severity, `${lrm(m.id)}: ${String(a.kind || "alarm").replaceAll("_", " ")}`];
  }
  const age = m.lastPacketAt === null ? Infinity : (now - m.lastPacketAt) / 1000;
  if (age > state.staleAfter && RANK.INVALID > RANK[sev]) {
    [sev, why] = ["INVALID", `${lrm(m.id)}: no data for ${fmtAge(age)}`];
  }
  return [sev, why];
}

// The top bar's state is the worst of its parts: INFO (modules switched off on purpose) is no fault
// but no "OK" either, so it ranks above OK here (unlike a module card's alarms).
const OVERALL_RANK = { OK: 0, INFO: 1, MINOR: 2, INVALID: 3, MAJOR: 4 };

/** The overall state and the reasons for it: the worst of the connection, the ingest, each module, the alarms. */
function overallState(parts) {
  let worst = "OK";
  for (const [sev] of parts) if (OVERALL_RANK[sev] > OVERALL_RANK[worst]) worst = sev;
  const why = joinModules([...new Set(parts.filter(([sev, w]) => sev === worst && w).map(([, w]) => w))]);
  const others = Object.keys(OVERALL_RANK)
    .filter((sev) => sev !== worst && sev !== "OK")
    .flatMap((sev) => joinModules([...new Set(parts.filter(([s, w]) => s === sev && w).map(([, w]) => w))]).map((w) => `${w} (${sev})`));
  return { worst, why, others };
}

/** "LRM-A signed off", "LRM-B signed off" -> "LRM-A, LRM-B signed off": the top bar has little room. */
function joinModules(reasons) {
  const out = [];
  const byTail = new Map();
  for (const r of reasons) {
    const m = /^(LRM-\S+?)(:? .*)$/.exec(r);
    if (!m) {
      out.push(r);
      continue;
    }
    if (!byTail.has(m[2])) {
      byTail.set(m[2], []);
      out.push(m[2]);
    }
    byTail.get(m[2]).push(m[1]);
  }
  return out.map((r) => (byTail.has(r) ? `${byTail.get(r).join(", ")}${r}` : r));
}

function systemParts(now) {
  const parts = [];
  if (state.conn !== "live") parts.push(["INVALID", "no connection to the ship"]);
  else if (state.serverError) parts.push(["MAJOR", "database down"]);
  const ingestAge = state.healthAt === null ? null : (now - state.healthAt) / 1000;
  if (stats.snapshotAt !== null && !(ingestAge !== null && ingestAge <= state.staleAfter)) {
    parts.push(["INVALID", "ingest down"]); // no data arrives from the modules (the banner says more)
  }
  if (stats.snapshotAt !== null && !state.modules.size) parts.push(["INVALID", "no module has reported"]);
  return parts;
}

function render() {
  const now = performance.now();
  renderHeader(now);
  const box = $("#modules");
  const ids = [...state.modules.keys()].sort();
  $("#no-modules")?.toggleAttribute("hidden", ids.length > 0);
  const parts = systemParts(now);
  for (const mid of ids) {
    const m = state.modules.get(mid);
    let card = cards.get(mid);
    if (!card) {
      card = createCard(mid);
      const after = [...cards.keys()].sort().find((k) => k > mid); // A before B, whoever spoke first
      box.insertBefore(card, after ? cards.get(after) : null);
      cards.set(mid, card);
      if (m.shown) {
        m.pending ??= { frame: m.shown, tEvent: null };
        loadThumbnail(m);
      }
    }
    const [severity, why] = moduleSeverity(m, now);
    parts.push([severity, why]);
    updateCard(card, m, { now, staleAfter: state.staleAfter, severity });
    updateQuality(card, m.quality, m.recent);
  }
  for (const [mid, card] of cards) {
    if (!state.modules.has(mid)) {
      card.remove();
      cards.delete(mid);
    }
  }
  for (const a of state.alarms.values()) {
    if (a.active && a.kind !== "signed_off" && !(a.module && state.modules.has(a.module))) {
      parts.push([a.severity, a.module ? `${lrm(a.module)}: ${String(a.kind || "alarm").replaceAll("_", " ")}` : String(a.message || a.kind)]);
    }
  }
  const { worst, why, others } = overallState(parts);
  const overall = $("#overall");
  overall.className = `pill big sev-${worst}`;
  overall.classList.toggle("unacked", [...state.alarms.values()].some((a) => a.active && a.severity === "MAJOR" && !a.acked_by));
  setText(overall, worst);
  const text = worst === "OK" ? "" : why.join(" · ");
  const reason = $("#overall-why");
  setText(reason, text);
  reason.hidden = !text;
  overall.title = reason.title = [`${worst}: the worst state of the connection, the ingest, the modules and the alarms`, ...why, ...others].join("\n");
  renderAlarms($("#alarms"), state.alarms, { operator: operator(), onAck: ack });
  renderAttenuation(now);
}

function renderHeader(now) {
  const conn = $("#conn");
  conn.dataset.state = state.conn;
  const banner = $("#banner");
  if (state.conn === "live") {
    setText(conn, "live");
  } else {
    const wait = state.connInfo.retryAt ? Math.max(0, (state.connInfo.retryAt - now) / 1000) : null;
    setText(conn, state.conn === "connecting" ? "connecting…" : "reconnecting…");
    if (stats.snapshotAt !== null) {
      banner.hidden = false;
      banner.className = "banner";
      const since = state.lastLiveAt ? `for ${fmtAge((now - state.lastLiveAt) / 1000)}` : "";
      setText(
        banner,
        `Connection to the ship server lost ${since} — reconnecting` +
          (wait !== null ? ` in ${wait.toFixed(0)} s (attempt ${state.connInfo.attempt})` : "…") +
          ". Values below are frozen and fade out when stale.",
      );
    }
  }
  if (state.serverError && state.conn !== "reconnecting") {
    // Connected, but the server cannot read its database: say so (not "connection lost").
    banner.hidden = false;
    banner.className = "banner major";
    setText(banner, `The ship server cannot show the live state: ${state.serverError}`);
  }
  const ingestAge = state.healthAt === null ? null : (now - state.healthAt) / 1000;
  const ingestUp = ingestAge !== null && ingestAge <= state.staleAfter;
  if (state.conn === "live" && !state.serverError) {
    if (!ingestUp && stats.snapshotAt !== null) {
      banner.hidden = false;
      banner.className = "banner major";
      setText(
        banner,
        ingestAge === null
          ? "The ingest has not reported to this server: no data is arriving from the modules (is it running? `camcal doctor` says)."
          : `The ingest has not reported for ${fmtAge(ingestAge)}: no new data is arriving from the modules.`,
      );
    } else {
      banner.hidden = true;
    }
  }
  setText($("#ingest-state"), `ingest ${ingestUp ? "up" : "down"}` + (state.linkSecurity === "plaintext" ? " · PLAINTEXT link" : ""));
  renderRefused($("#refused"), state.refused);
  setText($("#dive-name"), state.dive ? `${state.dive.name}` : "no dive yet");
  showDiveState($("#dive-state"), state.dive, $("#dive-notice"), ENDED_HINT);
}

/** The dive's state as the server reads it now (open, or ended and why): it changes without an event. */
async function refreshDive() {
  const id = state.dive?.id;
  if (!id) return;
  try {
    const d = await api(`/api/dives/${id}`);
    if (state.dive?.id === d.id) {
      state.dive = d;
      requestRender();
    }
  } catch {
    /* the next snapshot or round says it */
  }
}

async function ack(alarm, button) {
  button.disabled = true;
  try {
    const a = await api(`/api/alarms/${alarm.id}/ack`, { method: "POST", body: {} });
    state.alarms.set(a.id, { ...alarm, ...a });
    render();
  } catch (err) {
    toast(err.message);
    button.disabled = false;
  }
}

let attTimer = null;

function renderAttenuation(now) {
  const lost = state.conn !== "live" && state.lastLiveAt !== null && now - state.lastLiveAt > state.staleAfter * 1000;
  $("#attenuation-panel").classList.toggle("stale", lost);
  renderLambdaNow($("#att-now"), state.attenuation);
  if (!attDirty) return;
  if (now - attDrawnAt < 1000) {
    // At most one redraw a second: plotly is the costliest thing on the page.
    attTimer ??= setTimeout(() => {
      attTimer = null;
      requestRender();
    }, 1000 - (now - attDrawnAt));
    return;
  }
  attDirty = false;
  attDrawnAt = now;
  drawLambda($("#att-time"), $("#att-depth"), state.attenuation, Number($("#att-smooth").value));
}

// ------------------------------------------------------------------ start
initTheme($("#theme"));
mountOperator($("#operator"));
$("#att-smooth").addEventListener("change", () => {
  attDirty = true;
  requestRender();
});
window.addEventListener("camcal:auth", () => render());
window.addEventListener("camcal:theme", () => {
  attDirty = true;
  attDrawnAt = 0;
  render();
});
setInterval(render, 500); // ages tick and stale data fades even when nothing arrives
setInterval(refreshDive, DIVE_STATE_EVERY_MS);
new LiveSocket({ onSnapshot, onEvent, onMissed, onServerError, onState: onConn }).start();
