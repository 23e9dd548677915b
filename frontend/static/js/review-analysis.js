// Review: the λ_att table and series of a run, the linearity fits per module, attitude and housing.

import { api, query } from "./api.js";
import { fmt, fmtExposure, fmtPm, plural, wlColor } from "./format.js";
import { drawVisitSeries } from "./lambda-profile.js";
import { showChisqFit } from "./review-chisq.js";
import { draw, linearityFigure, stackedFigure } from "./plots.js";
import { $, el, lrm, setText, toast } from "./ui.js";

const MODULE_COLORS = ["#5cc8ff", "#ff9f43", "#c46bff", "#52e07a"];

export function runLabel(r) {
  if (r.kind === "live") return `#${r.id} · live run`;
  return `#${r.id} · ${r.label || "re-analysis"} (${r.status})`;
}

function fillRuns(select, runs, chosen) {
  select.replaceChildren(...runs.map((r) => el("option", { value: r.id }, runLabel(r))));
  select.value = String(chosen);
}

// ------------------------------------------------------------------ λ_att
/**
 * The span of the dive a λ_att table combines, shared by the λ_att tab and the comparison:
 * the station (the server's default: within 50 m of the deepest frame), the whole dive, or depths.
 */
export function spanParams(ctx) {
  const s = ctx.span || { mode: "station" };
  if (s.mode === "all") return { depth_min_m: 0 };
  if (s.mode === "depth") return { depth_min_m: s.min ?? 0, depth_max_m: s.max ?? "" };
  return {};
}

/** Fill every .span-control[data-for=<name>] of the page; onChange runs after the span changed. */
export function mountSpan(ctx, name, onChange) {
  const box = document.querySelector(`.span-control[data-for="${name}"]`);
  ctx.span ||= { mode: "station", min: null, max: null };
  const mode = el(
    "select",
    { name: "span", "aria-label": "span of the dive" },
    el("option", { value: "station" }, "the deepest 50 m (the station, once reached)"),
    el("option", { value: "all" }, "the whole dive"),
    el("option", { value: "depth" }, "a depth range"),
  );
  const num = (key, label) =>
    el("input", { type: "number", name: key, min: 0, step: "any", placeholder: label, "aria-label": label, style: { width: "6rem" } });
  const lo = num("span-min", "from m");
  const hi = num("span-max", "to m");
  const sync = () => {
    mode.value = ctx.span.mode;
    lo.value = ctx.span.min ?? "";
    hi.value = ctx.span.max ?? "";
    lo.hidden = hi.hidden = ctx.span.mode !== "depth";
  };
  const changed = () => {
    ctx.span = { mode: mode.value, min: lo.value === "" ? null : Number(lo.value), max: hi.value === "" ? null : Number(hi.value) };
    sync();
    onChange();
  };
  mode.onchange = changed;
  lo.onchange = changed;
  hi.onchange = changed;
  box.replaceChildren(el("label", {}, "span", el("span", { style: { display: "flex", gap: "0.4rem" } }, mode, lo, hi)));
  sync();
}

/** A depth band's name: the LEM's depth at a stop, or the range of a slice of a profile. */
function bandLabel(b) {
  if (b.depth_min_m === null || b.depth_max_m === null) return "depth unknown";
  return b.depth_max_m - b.depth_min_m < 30 ? `${fmt(b.depth_m, 0)} m` : `${fmt(b.depth_min_m, 0)}–${fmt(b.depth_max_m, 0)} m`;
}

/**
 * The λ_att table of one run: rows per wavelength with stat, sys and total errors and their pairs
 * (each with its LEM depth); a span that crosses depths gets a block of rows per depth band after
 * the span's own rows, which have no value when the bands' water differs (their note says so).
 */
export function attenuationTable(table, { caption } = {}) {
  const rows = table.rows || [];
  const bands = table.bands || [];
  const head = el(
    "thead",
    {},
    el(
      "tr",
      {},
      ...["λ", "λ_att (m)", "stat (m)", "sys (m)", "total (m)", "pairs", "χ²/ndof", "I0'/I0", "note"].map((h, i) =>
        el("th", { class: i && i < 8 ? "r" : "" }, h),
      ),
    ),
  );
  const body = el("tbody");
  const heading = (text, attrs = {}) => el("tr", { class: "band", ...attrs }, el("th", { colspan: 9, style: { textAlign: "left" } }, text));
  if (bands.length) body.append(heading(`the whole span, ${bands.length} depths`));
  for (const r of rows) body.append(...attenuationRows(r));
  for (const b of bands) {
    body.append(heading(`LEM depth ${bandLabel(b)} · ${plural(b.n_frames, "frame")}`, { "data-band": bandLabel(b) }));
    for (const r of b.rows) body.append(...attenuationRows(r, bandLabel(b)));
  }
  if (!rows.length) body.append(el("tr", {}, el("td", { colspan: 9, class: "empty" }, "No λ_att in this span: no near/far pairs of equal setting with frames in range.")));
  const t = el("table", {}, head, body);
  if (caption) t.prepend(el("caption", { class: "muted", style: { textAlign: "left" } }, caption));
  return t;
}

function attenuationRows(r, depth = null) {
  const out = [
    el(
      "tr",
      { "data-wl": r.wavelength_nm, ...(depth ? { "data-depth": depth } : {}) },
      el("td", { style: { color: wlColor(r.wavelength_nm), fontWeight: 700 } }, `${r.wavelength_nm} nm`),
      el("td", { class: "r", style: { fontWeight: 700, fontSize: "1.15rem" } }, fmt(r.lambda_att_m, 2)),
      el("td", { class: "r" }, fmt(r.stat_err_m, 2)),
      el("td", { class: "r" }, fmt(r.sys_err_m, 2)),
      el("td", { class: "r" }, fmt(r.total_err_m, 2)),
      el("td", { class: "r" }, r.n_pairs),
      el("td", { class: "r", title: r.n_pairs > 1 ? "" : "one pair: no degree of freedom" }, r.n_pairs > 1 ? fmt(r.chi2_ndof, 2) : "–"),
      el("td", { class: "r" }, `${fmt(r.emission_ratio, 3)} ± ${fmt(r.emission_ratio_err, 3)}`),
      el("td", { class: "muted", style: { whiteSpace: "normal", minWidth: "12rem" } }, r.note || ""),
    ),
  ];
  if (r.pairs?.length) {
    out.push(
      el(
        "tr",
        { class: "pairs" },
        el(
          "td",
          { colspan: 9, style: { whiteSpace: "normal" } },
          el(
            "details",
            {},
            el("summary", { class: "muted" }, `${plural(r.pairs.length, "near/far pair")} of ${r.wavelength_nm} nm${depth ? ` at ${depth}` : ""}`),
            pairsTable(r.pairs),
          ),
        ),
      ),
    );
  }
  return out;
}

function pairsTable(pairs) {
  return el(
    "table",
    {},
    el("thead", {}, el("tr", {}, ...["LEM depth", "exposure", "gain", "I near (gray)", "I far (gray)", "frames near/far", "λ_att (m)", "stat (m)"].map((h) => el("th", { class: "r" }, h)))),
    el(
      "tbody",
      {},
      ...pairs.map((p) =>
        el(
          "tr",
          {},
          el("td", { class: "r" }, p.depth_m === null || p.depth_m === undefined ? "–" : `${fmt(p.depth_m, 0)} m`),
          el("td", { class: "r" }, fmtExposure(p.exposure_s)),
          el("td", { class: "r" }, `${fmt(p.gain_db, 0)} dB`),
          el("td", { class: "r" }, `${fmt(p.i_near_gray, 2)} ± ${fmt(p.i_near_err_gray, 2)}`),
          el("td", { class: "r" }, `${fmt(p.i_far_gray, 2)} ± ${fmt(p.i_far_err_gray, 2)}`),
          el("td", { class: "r" }, `${p.n_near} / ${p.n_far}`),
          el("td", { class: "r" }, fmt(p.lambda_att_m, 2)),
          el("td", { class: "r" }, fmt(p.stat_err_m, 2)),
        ),
      ),
    ),
  );
}

/** Point the export links at a run of the dive (null: the live run, the server's default). */
export function exportRun(diveId, runId) {
  for (const fmt of ["csv", "parquet"]) {
    const a = $(`#export-${fmt}`);
    a.href = `/api/dives/${diveId}/export?format=${fmt}${runId ? `&run=${runId}` : ""}`;
    a.title = `the dive's tables${runId ? ` with the results of run #${runId}` : ""} as ${fmt} files in a ZIP`;
  }
  setText($("#export-label"), runId ? `export the dive, run #${runId}:` : "export the dive:");
}

export async function showAttenuation(ctx) {
  const select = $("#att-run");
  fillRuns(select, ctx.runs, select.dataset.dive === String(ctx.dive.id) && select.value ? select.value : ctx.liveRunId);
  select.dataset.dive = ctx.dive.id;
  select.onchange = () => loadAttenuation(ctx, Number(select.value));
  mountSpan(ctx, "attenuation", () => loadAttenuation(ctx, Number(select.value)));
  await loadAttenuation(ctx, Number(select.value));
}

function describeSpan(sp, mode) {
  const lo = sp.depth_min_m;
  const hi = sp.depth_max_m;
  if (!lo && hi === null) return "the whole dive";
  const depths = `depth ${fmt(lo || 0, 0)}${hi === null ? "+ m" : `–${fmt(hi, 0)} m`}`;
  // "the station" only names it: on the way down the deepest 50 m are wherever the modules are now
  return mode === "station" ? `the deepest 50 m so far, ${depths}` : depths;
}

async function loadAttenuation(ctx, runId) {
  const id = ctx.dive.id;
  exportRun(id, runId === ctx.liveRunId ? null : runId); // the export takes the run the tab shows
  try {
    const [table, series] = await Promise.all([
      api(`/api/dives/${id}/attenuation${query({ run: runId, ...spanParams(ctx) })}`),
      api(`/api/attenuation${query({ dive: id, run: runId })}`),
    ]);
    const sp = table.span;
    setText(
      $("#att-span"),
      `${describeSpan(sp, ctx.span?.mode)}: ${sp.n_frames} frames${sp.note ? ` — ${sp.note}` : ""}`,
    );
    $("#att-table").replaceWith(Object.assign(attenuationTable(table), { id: "att-table" }));
    showChisqFit($("#chisq-fit"), ctx.dive, runId).catch((err) => toast(err.message));
    const smooth = $("#att-series-smooth");
    const redraw = () =>
      drawVisitSeries($("#att-series-time"), $("#att-series-depth"), series.series, {
        smoothVisits: Number(smooth.value),
        filename: `camcal-${ctx.dive.name}-run${runId}-lambda-att`,
        emptyText: "no λ_att points in this run",
      });
    smooth.onchange = () => redraw().catch((err) => toast(err.message));
    await redraw();
  } catch (err) {
    toast(err.message);
  }
}

// ------------------------------------------------------------------ linearity
export async function showLinearity(ctx) {
  const box = $("#linearity");
  let data;
  try {
    data = await api(`/api/linearity${query({ dive: ctx.dive.id, run: ctx.liveRunId })}`);
  } catch (err) {
    box.replaceChildren(el("p", { class: "error-msg" }, err.message));
    return;
  }
  const modules = [...new Set(data.checks.map((c) => c.module))].sort();
  if (!modules.length) {
    box.replaceChildren(el("div", { class: "panel" }, el("p", { class: "empty" }, "No linearity fits yet: they need ≥ 3 in-range settings per module and wavelength.")));
    return;
  }
  box.replaceChildren();
  const jobs = [];
  for (const m of modules) {
    const checks = data.checks.filter((c) => c.module === m);
    const panel = el("div", { class: "panel", "data-module": m }, el("h2", {}, `${lrm(m)}: linearity of the centre gray`));
    const plots = el("div", { class: "grid-2" });
    panel.append(plots);
    box.append(panel); // in the page first: the figures size their ticks to their width
    for (const sweep of ["exposure", "gain"]) {
      const cs = checks.filter((c) => c.sweep === sweep);
      if (!cs.length) continue;
      const div = el("div", { class: "plot", id: `lin-${m}-${sweep}` });
      const fixed = cs.map((c) => (sweep === "exposure" ? `${fmt(c.fixed_value, 0)} dB` : fmtExposure(c.fixed_value)));
      plots.append(el("div", {}, el("h3", {}, sweep === "exposure" ? `against exposure (at gain ${[...new Set(fixed)].join(", ")})` : `against gain (at exposure ${[...new Set(fixed)].join(", ")})`), div));
      const fig = linearityFigure(cs, sweep, div.clientWidth);
      jobs.push(draw(div, fig.traces, fig.layout, `camcal-${ctx.dive.name}-${m}-linearity-${sweep}`));
    }
    panel.append(fitsTable(checks));
  }
  await Promise.all(jobs);
}

function fitsTable(checks) {
  return el(
    "div",
    { class: "table-wrap" },
    el(
      "table",
      { class: "fits" },
      el("thead", {}, el("tr", {}, ...["λ", "sweep", "at", "slope", "R²", "points", "linear to", "knee"].map((h, i) => el("th", { class: i > 2 ? "r" : "" }, h)))),
      el(
        "tbody",
        {},
        ...checks.map((c) =>
          el(
            "tr",
            {},
            el("td", { style: { color: wlColor(c.wavelength_nm), fontWeight: 700 } }, `${c.wavelength_nm} nm`),
            el("td", {}, c.sweep),
            el("td", {}, c.sweep === "exposure" ? `${fmt(c.fixed_value, 0)} dB` : fmtExposure(c.fixed_value)),
            el(
              "td",
              { class: "r", title: `intercept ${fmt(c.intercept_gray, 2)} gray` },
              `${fmtPm(c.slope, c.slope_err)} ${c.sweep === "exposure" ? "gray/s" : "gray per ×1 gain"}`,
            ),
            el("td", { class: "r", "data-r2": c.r2 }, c.r2 === null ? "–" : c.r2.toFixed(4)),
            el("td", { class: "r" }, c.n_used),
            el("td", { class: "r" }, `${fmt(c.linear_max_gray, 0)} gray`),
            el("td", { class: "r" }, c.knee_x ? (c.sweep === "exposure" ? fmtExposure(c.knee_x) : `${fmt(20 * Math.log10(c.knee_x), 0)} dB`) : "none"),
          ),
        ),
      ),
    ),
  );
}

// ------------------------------------------------------------------ attitude and housing
export async function showAttitude(ctx) {
  const modules = ctx.settings?.modules?.length ? ctx.settings.modules : ["A", "B"];
  let att;
  let sens;
  try {
    [att, sens] = await Promise.all([
      Promise.all(modules.map((m) => api(`/api/attitude${query({ dive: ctx.dive.id, module: m, max_points: 1500 })}`))),
      Promise.all(modules.map((m) => api(`/api/sensors${query({ dive: ctx.dive.id, module: m, max_points: 1500 })}`))),
    ]);
  } catch (err) {
    toast(err.message);
    return;
  }
  const color = (i) => MODULE_COLORS[i % MODULE_COLORS.length];
  // The first module solid and wide, the others dotted and thin over it: where they agree (housing,
  // depth), both stay in sight.
  const series = (data, key) =>
    data.map((d, i) => ({ name: `${lrm(modules[i])}`, t: d.t_unix_s, y: d[key], color: color(i), dash: i ? "dot" : "solid", width: i ? 1.5 : 2.5 }));
  const a = stackedFigure([
    { title: "tilt (°)", series: series(att, "tilt_deg") },
    { title: "rotation (°/s)", series: series(att, "rotation_rate_dps") },
    { title: "heave period (s)", series: series(att, "heave_period_s") },
  ]);
  const h = stackedFigure([
    { title: "housing (°C)", series: series(sens, "temperature_c") },
    { title: "humidity (%)", series: series(sens, "humidity_pct") },
    { title: "depth (m)", series: series(sens, "depth_m") },
  ]);
  h.layout.yaxis3 = { ...h.layout.yaxis3, autorange: "reversed" };
  const note = att.some((d) => d.downsampled) ? " (averaged into buckets)" : "";
  await Promise.all([
    draw($("#attitude-plot"), a.traces, { ...a.layout, title: { text: `attitude over the dive${note}` } }, `camcal-${ctx.dive.name}-attitude`),
    draw($("#housing-plot"), h.traces, { ...h.layout, title: { text: "housing temperature, humidity and depth" } }, `camcal-${ctx.dive.name}-housing`),
  ]);
}
