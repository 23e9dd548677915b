// Review: re-analysis with other calibration inputs (a new run; the original stays), the runs and
// their progress, and two runs' λ_att side by side.

import { api, operator, query } from "./api.js";
import { fmt, plural, utc, wlColor } from "./format.js";
import { mountSpan, runLabel, spanParams } from "./review-analysis.js";
import { $, el, lrm, toast } from "./ui.js";

let poll = null;
let current = null;
/** Stored calibration records (GET /api/calibrations), offered as starting points. */
let calibrations = [];

function input(name, value, title) {
  return el("input", { type: "number", name, value: value ?? "", step: "any", min: 0, required: true, "aria-label": title || name });
}

/** One row "label [value] ± [error] unit" of the form. */
function pair(label, name, value, err, unit) {
  return el(
    "div",
    { class: "pair" },
    el("span", {}, label),
    input(`${name}-v`, value, `${typeof label === "string" ? label : name} value`),
    el("span", {}, "±"),
    input(`${name}-e`, err, `${typeof label === "string" ? label : name} error`),
    el("span", {}, unit),
  );
}

/** Where a run's values came from, when not from the run itself. */
const FROM = { dive: " (the frame set's setup.json)", defaults: " (T-REX's defaults)" };

/** The form, filled with the live run's calibration: change what you want to try. */
function buildForm(ctx, from = null) {
  const f = $("#reanalysis-form");
  const live = ctx.runs.find((r) => r.id === ctx.liveRunId) || ctx.runs[0];
  const record = from === null ? null : calibrations.find((c) => c.id === from);
  const cal = record ? record.values?.setup || {} : live?.setup || {};
  const cams = cal.cameras || {};
  const ratios = cal.emission_ratio || {};
  const [lo, hi] = cal.linear_range || [5, 240];
  const op = operator();
  const start = el(
    "select",
    { name: "from", "aria-label": "start from", onchange: (ev) => buildForm(ctx, ev.target.value ? Number(ev.target.value) : null) },
    el("option", { value: "" }, `the live run's calibration${FROM[live?.setup_from] || ""}`),
    ...calibrations.map((c) => el("option", { value: c.id }, `calibration record ${c.name} v${c.version}${c.source ? ` (${c.source})` : ""}`)),
  );
  start.value = record ? String(record.id) : "";
  f.replaceChildren(
    el(
      "div",
      { class: "filters" },
      el("label", {}, "start from", start),
      el(
        "span",
        { class: "muted" },
        record
          ? "the run records this calibration; what you change below overrides its values"
          : calibrations.length
            ? "or pick a stored calibration record"
            : "",
      ),
    ),
    el(
      "div",
      { class: "form-grid" },
      el(
        "fieldset",
        {},
        el("legend", {}, "Distances to the LEM"),
        ...Object.keys(cams)
          .sort()
          .map((m) => pair(`${lrm(m)}`, `cam-${m}`, cams[m].distance_m, cams[m].distance_err_m, "m")),
      ),
      el(
        "fieldset",
        {},
        el("legend", {}, "Module clocks ahead of true time"),
        ...Object.keys(cams)
          .sort()
          .map((m) =>
            el(
              "div",
              { class: "pair", title: "a module clock that was off (the ship's clock alarm says how far): its frames are paired with the other camera's at the corrected times; behind: negative" },
              el("span", {}, `${lrm(m)}`),
              el("input", { type: "number", name: `clock-${m}`, value: cams[m].clock_offset_s ?? 0, step: "any", min: -1e9, max: 1e9, required: true, "aria-label": `${lrm(m)} clock offset` }),
              el("span", {}, "s"),
            ),
          ),
      ),
      el(
        "fieldset",
        {},
        el("legend", {}, "Emission ratio I0'/I0 (far / near)"),
        ...Object.keys(ratios)
          .sort()
          .map((wl) => pair(el("span", { style: { color: wlColor(wl), fontWeight: 700 } }, `${wl} nm`), `er-${wl}`, ratios[wl].value, ratios[wl].err, "")),
      ),
      el(
        "fieldset",
        {},
        el("legend", {}, "Linear range of the centre gray"),
        el(
          "div",
          { class: "pair", title: "frames whose LEM pixels fall outside are rejected" },
          el("span", {}, "gray"),
          input("lin-lo", lo, "linear range low"),
          el("span", {}, "to"),
          input("lin-hi", hi, "linear range high"),
          el("span"),
        ),
      ),
      el(
        "fieldset",
        {},
        el("legend", {}, "Name of the run"),
        el("input", { type: "text", name: "label", maxlength: 200, placeholder: "e.g. B at 41.70 m", "aria-label": "label", style: { width: "100%" } }),
      ),
    ),
    el(
      "div",
      { style: { display: "flex", gap: "0.8rem", alignItems: "center", marginTop: "0.7rem", flexWrap: "wrap" } },
      el("button", { type: "submit", class: "primary", id: "reanalysis-submit", disabled: !op }, "Start re-analysis"),
      el("button", { type: "button", onclick: () => buildForm(ctx, from) }, "Reset the values"),
      el("span", { class: op ? "muted" : "error-msg", id: "reanalysis-note" }, op ? `as ${op.name}` : "Log in as operator to start a re-analysis."),
    ),
  );
  f.onsubmit = (ev) => {
    ev.preventDefault();
    submit(ctx, f, cams, ratios, record ? record.id : null);
  };
}

async function submit(ctx, f, cams, ratios, calibrationId) {
  const v = (n) => Number(f.elements[n].value);
  const body = {
    label: f.elements.label.value.trim(),
    cameras: Object.fromEntries(
      Object.keys(cams).map((m) => [m, { distance_m: v(`cam-${m}-v`), distance_err_m: v(`cam-${m}-e`), clock_offset_s: v(`clock-${m}`) }]),
    ),
    emission_ratio: Object.fromEntries(Object.keys(ratios).map((wl) => [wl, { value: v(`er-${wl}-v`), err: v(`er-${wl}-e`) }])),
    linear_range: [v("lin-lo"), v("lin-hi")],
  };
  if (calibrationId !== null) body.calibration_id = calibrationId;
  await start(ctx, body, $("#reanalysis-submit"));
}

/** Start a re-analysis (POST ``body``), show it beside the live run and follow it. */
async function start(ctx, body, button) {
  button.disabled = true;
  try {
    const run = await api(`/api/dives/${ctx.dive.id}/reanalyses`, { method: "POST", body });
    toast(`re-analysis #${run.id} started`, { kind: "info" });
    ctx.runs.push(run);
    $("#cmp-right").dataset.want = run.id;
    await refreshRuns(ctx);
  } catch (err) {
    toast(err.message);
  } finally {
    button.disabled = !operator();
  }
}

/** The same re-analysis again, for one that did not finish: its calibration, its record, its name. */
function runAgain(ctx, r) {
  const c = r.setup;
  const body = {
    label: `${r.label || `run #${r.id}`} (again)`.slice(0, 200),
    cameras: Object.fromEntries(
      Object.entries(c.cameras || {}).map(([m, d]) => [m, { distance_m: d.distance_m, distance_err_m: d.distance_err_m ?? 0, clock_offset_s: d.clock_offset_s ?? 0 }]),
    ),
    emission_ratio: Object.fromEntries(Object.entries(c.emission_ratio || {}).map(([wl, e]) => [wl, { value: e.value, err: e.err ?? 0 }])),
  };
  if (c.linear_range) body.linear_range = c.linear_range;
  if (r.calibration_id !== null && r.calibration_id !== undefined) body.calibration_id = r.calibration_id;
  return (ev) => start(ctx, body, ev.currentTarget);
}

/** The live run: ongoing while frames come (one in the last 10 min), else when the last came. */
function liveText(dive) {
  const last = dive.last_frame_unix_s;
  if (!last) return "live (no frame yet)";
  return Date.now() / 1000 - last < 600 ? "live (ongoing)" : `live (last frame ${utc(last)})`;
}

/** A run's status, with what to do when it did not finish (and, for an operator, a button to do it). */
function statusCell(ctx, r) {
  const text = r.kind === "live" && r.status === "running" ? liveText(ctx.dive) : r.status;
  const cell = el("td", { title: r.note || "" }, el("span", { class: "run-status", "data-status": r.status }, text));
  if (r.kind !== "live" && ["interrupted", "failed", "cancelled"].includes(r.status)) {
    if (r.note) cell.append(el("div", { class: "muted run-note" }, r.note));
    if (operator()) cell.append(el("button", { type: "button", class: "run-again", onclick: runAgain(ctx, r) }, "Run again"));
  }
  return cell;
}

/** Frames analysed by a re-analysis, against the dive's frames. */
function progress(ctx, r) {
  const n = Math.max(ctx.dive.n_frames || 0, r.n_frames);
  if (!n || r.status !== "running") return `${r.n_frames} frames`;
  const pct = Math.min(100, Math.round((100 * r.n_frames) / n));
  return el("span", {}, el("progress", { max: 100, value: pct, style: { width: "6rem", verticalAlign: "middle" } }), ` ${r.n_frames} / ${n}`);
}

function renderRuns(ctx) {
  const t = $("#runs-table");
  t.replaceChildren(
    el("thead", {}, el("tr", {}, ...["run", "kind", "label", "created (UTC)", "status", "progress", "distances (m)", "I0'/I0", "linear range (gray)"].map((h) => el("th", {}, h)))),
    el(
      "tbody",
      {},
      ...ctx.runs.map((r) => {
        const c = r.setup;
        return el(
          "tr",
          { "data-run-id": r.id },
          el("td", {}, `#${r.id}`),
          el("td", {}, r.kind),
          el("td", {}, r.label || "–"),
          el("td", {}, utc(r.created_unix_s)),
          statusCell(ctx, r),
          el("td", { class: "r" }, r.kind === "live" ? `${r.n_frames} of ${plural(ctx.dive.n_frames || 0, "frame")}` : progress(ctx, r)),
          el("td", { style: { whiteSpace: "normal" } }, Object.entries(c.cameras || {}).map(([m, d]) => `${m} ${fmt(d.distance_m, 2)} ± ${fmt(d.distance_err_m, 2)} m` + (d.clock_offset_s ? ` (clock ${d.clock_offset_s > 0 ? "+" : ""}${fmt(d.clock_offset_s, 1)} s)` : "")).join(", ")),
          el("td", { style: { whiteSpace: "normal" } }, Object.entries(c.emission_ratio || {}).map(([wl, e]) => `${wl} nm: ${fmt(e.value, 3)} ± ${fmt(e.err, 3)}`).join(", ")),
          el("td", {}, c.linear_range ? `${c.linear_range[0]}–${c.linear_range[1]}` : "–"),
        );
      }),
    ),
  );
}

/** Reload the runs; poll while one is still running (a re-analysis), then compare again. */
async function refreshRuns(ctx) {
  clearTimeout(poll);
  try {
    const [runs, dive] = await Promise.all([api(`/api/dives/${ctx.dive.id}/runs`), api(`/api/dives/${ctx.dive.id}`)]);
    ctx.runs = runs;
    ctx.dive.n_frames = dive.n_frames;
    ctx.dive.last_frame_unix_s = dive.last_frame_unix_s;
  } catch (err) {
    toast(err.message);
  }
  if (current !== ctx) return;
  renderRuns(ctx);
  fillCompare(ctx);
  await compare(ctx);
  if (ctx.runs.some((r) => r.kind !== "live" && (r.status === "running" || r.status === "queued"))) {
    poll = setTimeout(() => refreshRuns(ctx), 1500);
  }
}

function fillCompare(ctx) {
  const left = $("#cmp-left");
  const right = $("#cmp-right");
  const others = ctx.runs.filter((r) => r.id !== ctx.liveRunId);
  const keepL = left.value || ctx.liveRunId;
  const keepR = right.dataset.want || right.value || (others.length ? others[others.length - 1].id : ctx.liveRunId);
  delete right.dataset.want;
  for (const [s, keep] of [
    [left, keepL],
    [right, keepR],
  ]) {
    s.replaceChildren(...ctx.runs.map((r) => el("option", { value: r.id }, runLabel(r))));
    s.value = String(keep);
    s.onchange = () => compare(ctx);
  }
}

async function compare(ctx) {
  const l = Number($("#cmp-left").value);
  const r = Number($("#cmp-right").value);
  const table = $("#cmp-table");
  if (!l || !r) return;
  if (ctx.runs.length < 2) {
    table.replaceChildren(el("caption", { class: "empty", style: { textAlign: "left" } }, "Only the live run so far: start a re-analysis above to compare it with."));
    return;
  }
  let a;
  let b;
  try {
    [a, b] = await Promise.all(
      [l, r].map((run) => api(`/api/dives/${ctx.dive.id}/attenuation${query({ run, ...spanParams(ctx) })}`)),
    );
  } catch (err) {
    table.replaceChildren(el("caption", { class: "error-msg" }, err.message));
    return;
  }
  const runOf = (id) => ctx.runs.find((x) => x.id === id);
  const byWl = (t) => Object.fromEntries(t.rows.map((row) => [row.wavelength_nm, row]));
  const A = byWl(a);
  const B = byWl(b);
  const wls = [...new Set([...Object.keys(A), ...Object.keys(B)])].sort();
  const cell = (row) => (row ? `${fmt(row.lambda_att_m, 2)} ± ${fmt(row.stat_err_m, 2)} stat ± ${fmt(row.sys_err_m, 2)} sys` : "–");
  const rightRun = runOf(r);
  table.replaceChildren(
    el(
      "thead",
      {},
      el(
        "tr",
        {},
        el("th", {}, "λ"),
        el("th", { class: "r" }, `${runLabel(runOf(l) || { id: l, kind: "", status: "" })}: λ_att (m)`),
        el("th", { class: "r" }, `${runLabel(rightRun || { id: r, kind: "", status: "" })}: λ_att (m)`),
        el("th", { class: "r" }, "difference (m)"),
        el("th", { class: "r" }, "difference"),
      ),
    ),
    el(
      "tbody",
      {},
      ...wls.map((wl) => {
        const x = A[wl];
        const y = B[wl];
        const d = x && y && x.lambda_att_m !== null && y.lambda_att_m !== null ? y.lambda_att_m - x.lambda_att_m : null;
        return el(
          "tr",
          { "data-wl": wl },
          el("td", { style: { color: wlColor(wl), fontWeight: 700 } }, `${wl} nm`),
          el("td", { class: "r" }, cell(x)),
          el("td", { class: "r" }, cell(y)),
          el("td", { class: `r ${d > 0 ? "delta-pos" : d < 0 ? "delta-neg" : ""}` }, d === null ? "–" : `${d > 0 ? "+" : ""}${fmt(d, 2)}`),
          el("td", { class: "r" }, d === null ? "–" : `${d > 0 ? "+" : ""}${fmt((100 * d) / x.lambda_att_m, 1)} %`),
        );
      }),
      ...(wls.length ? [] : [el("tr", {}, el("td", { colspan: 5, class: "empty" }, "no λ_att in either run yet"))]),
    ),
  );
  if (rightRun && rightRun.status === "running") {
    table.append(el("caption", { class: "muted", style: { captionSide: "bottom", textAlign: "left" } }, `run #${rightRun.id} is still running: its numbers grow as it goes`));
  }
}

export async function showReanalysis(ctx) {
  current = ctx;
  calibrations = await api("/api/calibrations").catch(() => []);
  buildForm(ctx);
  mountSpan(ctx, "compare", () => compare(ctx));
  await refreshRuns(ctx);
}

window.addEventListener("camcal:auth", () => {
  const op = operator();
  const button = $("#reanalysis-submit");
  const note = $("#reanalysis-note");
  if (!button || !note) return;
  button.disabled = !op;
  note.className = op ? "muted" : "error-msg";
  note.textContent = op ? `as ${op.name}` : "Log in as operator to start a re-analysis.";
  if (current) renderRuns(current); // the "Run again" buttons are an operator's
});
