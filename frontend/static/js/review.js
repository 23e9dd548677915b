// The review view: pick a dive, then its sections as tabs. The address keeps the dive, the tab
// and an opened frame (#dive=3&tab=frames&frame=120), so a link shows a colleague the same thing.

import { api } from "./api.js";
import { fmt, utc } from "./format.js";
import { exportRun, showAttenuation, showAttitude, showLinearity } from "./review-analysis.js";
import { openFrame, showFrames } from "./review-frames.js";
import { showAudit } from "./review-audit.js";
import { showReanalysis } from "./review-runs.js";
import { $, el, initTheme, mountOperator, setText, showDiveState, showSimulation } from "./ui.js";

const TABS = {
  frames: showFrames,
  attenuation: showAttenuation,
  linearity: showLinearity,
  attitude: showAttitude,
  reanalysis: showReanalysis,
  audit: showAudit,
};
/** Tabs drawn again each time they are shown (the others once per dive). */
const FRESH = new Set(["audit", "reanalysis", "attenuation"]);

const ctx = { dives: [], dive: null, settings: null, runs: [], liveRunId: null, loaded: new Set(), tab: "frames" };
window.camcalReview = ctx;

function params() {
  return new URLSearchParams(location.hash.slice(1));
}

function setParams(update) {
  const p = params();
  for (const [k, v] of Object.entries(update)) {
    if (v === null || v === undefined) p.delete(k);
    else p.set(k, v);
  }
  history.replaceState(null, "", `#${p}`);
}

function showError(message) {
  const box = $("#review-error");
  box.hidden = !message;
  box.textContent = message || "";
}

async function loadDives() {
  try {
    ctx.dives = await api("/api/dives");
  } catch (err) {
    showError(err.message);
    return;
  }
  const select = $("#dive-select");
  select.replaceChildren(
    ...ctx.dives.map((d) =>
      el(
        "option",
        { value: d.id, title: `${d.state}: ${d.state_reason}` },
        `${d.name} · ${d.state} · ${d.n_frames} frames${d.max_depth_m ? ` · ${fmt(d.max_depth_m, 0)} m` : ""}`,
      ),
    ),
  );
  if (!ctx.dives.length) {
    showError("No dives in this data folder yet: start one with `camcal up` or import one.");
    return;
  }
  const want = Number(params().get("dive"));
  const dive = ctx.dives.find((d) => d.id === want) || ctx.dives[0];
  select.value = String(dive.id);
  await selectDive(dive.id);
}

async function selectDive(id) {
  showError("");
  const dive = ctx.dives.find((d) => d.id === id);
  ctx.dive = dive;
  ctx.loaded = new Set();
  setParams({ dive: id });
  // When the ship received its frames (its own clock): a simulated module's clock runs ahead of it.
  const span = dive.first_received_unix_s
    ? `frames received ${utc(dive.first_received_unix_s, { date: false })}–${utc(dive.last_received_unix_s, { date: false })} UTC`
    : "no frames";
  setText($("#dive-summary"), span);
  showDiveState($("#dive-state"), dive, $("#dive-notice"));
  exportRun(id, null);
  try {
    const [settings, runs] = await Promise.all([
      api(`/api/dives/${id}/settings`).catch(() => null),
      api(`/api/dives/${id}/runs`).catch(() => []),
    ]);
    ctx.settings = settings;
    ctx.runs = runs;
    const live = runs.find((r) => r.kind === "live");
    ctx.liveRunId = live ? live.id : runs.length ? runs[runs.length - 1].id : null;
  } catch (err) {
    showError(err.message);
  }
  await showTab(params().get("tab") || ctx.tab);
}

async function showTab(tab) {
  if (!TABS[tab]) tab = "frames";
  ctx.tab = tab;
  setParams({ tab });
  for (const b of document.querySelectorAll(".tabs [data-tab]")) b.setAttribute("aria-selected", String(b.dataset.tab === tab));
  for (const s of document.querySelectorAll("main > [role=tabpanel]")) s.hidden = s.dataset.tab !== tab;
  if (!ctx.dive) return;
  if (ctx.loaded.has(tab) && !FRESH.has(tab)) return;
  ctx.loaded.add(tab);
  try {
    await TABS[tab](ctx);
  } catch (err) {
    showError(err.message);
  }
  const frame = Number(params().get("frame"));
  if (tab === "frames" && frame) openFrame(frame);
}

initTheme($("#theme"));
mountOperator($("#operator"));
for (const b of document.querySelectorAll(".tabs [data-tab]")) b.addEventListener("click", () => showTab(b.dataset.tab));
$("#dive-select").addEventListener("change", (ev) => selectDive(Number(ev.target.value)));
window.addEventListener("camcal:theme", () => {
  ctx.loaded = new Set();
  showTab(ctx.tab);
});
loadDives();
api("/api/health")
  .then((h) => showSimulation(h.server?.simulation_speed))
  .catch(() => {}); // only the note in the top bar: the page works without it
