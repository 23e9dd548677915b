// λ_att per LEM visit: the series against time and the profile against the LEM's depth, side by
// side. Every point is one visit, with thick bars for its statistical error and thin ones for
// statistical ⊕ systematic; a provisional point (its visit still running) is drawn hollow.
// Smoothing (a mean over several visits) is a display option only, its span in the legend.

import { fmt, plotDate, utc, wlColor } from "./format.js";
import { draw, emptyPlot, timeAxis } from "./plots.js";

const hasValue = (p) => p.lambda_att_m !== null && p.lambda_att_m !== undefined;
/** A point's time on the ship's clock, the dive's one axis (its frames' module times mapped onto it). */
export const shipT = (p) => p.t_ship_unix_s ?? p.t_unix_s;

/**
 * Put a live `attenuation` event into a series {"405": [points]}: a visit's newer point replaces
 * its older one (same visit_key), a deleted visit goes, the points stay in time order.
 * @returns {boolean} whether anything changed
 */
export function upsertVisit(series, p, { keep = 600 } = {}) {
  const key = p.visit_key;
  if (p.deleted) {
    let changed = false;
    for (const wl of Object.keys(series)) {
      const before = series[wl].length;
      series[wl] = series[wl].filter((q) => q.visit_key !== key);
      changed ||= series[wl].length !== before;
    }
    return changed;
  }
  const wl = String(p.wavelength_nm);
  const pts = (series[wl] ||= []);
  const point = { ...p, id: p.point_id ?? p.id };
  const i = key ? pts.findIndex((q) => q.visit_key === key) : -1;
  if (i >= 0) pts[i] = point;
  else pts.push(point);
  pts.sort((a, b) => shipT(a) - shipT(b));
  if (pts.length > keep) {
    // the points stored first go (numbered as their visits begin), not those of the earliest times
    const cut = pts.map((q) => q.id ?? -1).sort((a, b) => a - b)[pts.length - keep];
    series[wl] = pts.filter((q) => (q.id ?? -1) >= cut);
  }
  return true;
}

function hover(p) {
  const state = p.final === false ? "provisional (visit running)" : "final";
  return (
    `λ ${fmt(p.lambda_att_m, 2)} m ± ${fmt(p.stat_err_m, 2)} stat ± ${fmt(p.sys_err_m, 2)} sys<br>` +
    `LEM depth ${fmt(p.depth_m, 0)} m · ${utc(shipT(p))}<br>` +
    `${p.n_frames ?? "?"} frames, ${p.n_pairs} pairs · ${state}`
  );
}

/** Error bars and markers of one wavelength against time ("time") or depth ("depth"). */
function pointTraces(wl, pts, against) {
  const color = wlColor(wl);
  const lam = pts.map((p) => p.lambda_att_m);
  const other = against === "time" ? pts.map((p) => plotDate(shipT(p))) : pts.map((p) => p.depth_m);
  const xy = (vals) => (against === "time" ? { x: other, y: vals } : { x: vals, y: other });
  const errKey = against === "time" ? "error_y" : "error_x";
  const bars = (arr, thickness, width) => ({ type: "data", array: arr, visible: true, color, thickness, width });
  const total = pts.map((p) => Math.hypot(p.stat_err_m ?? 0, p.sys_err_m ?? 0));
  return [
    {
      ...xy(lam),
      type: "scatter",
      mode: "markers",
      marker: { size: 1, color, opacity: 0 },
      [errKey]: bars(total, 1, 0),
      hoverinfo: "skip",
      showlegend: false,
      legendgroup: wl,
      opacity: 0.55,
    },
    {
      ...xy(lam),
      type: "scatter",
      mode: "markers",
      name: `${wl} nm`,
      legendgroup: wl,
      marker: {
        color,
        size: 8,
        symbol: pts.map((p) => (p.final === false ? "circle-open" : "circle")),
        line: { color, width: 2 },
      },
      [errKey]: bars(
        pts.map((p) => p.stat_err_m ?? 0),
        2.5,
        4,
      ),
      text: pts.map(hover),
      hovertemplate: `${wl} nm<br>%{text}<extra></extra>`,
    },
  ];
}

/**
 * Means over `n` consecutive visits of a wavelength (inverse-variance weighted, centred), with the
 * time those visits span: a display aid, never stored.
 */
export function smoothed(pts, n) {
  const out = [];
  const half = Math.floor(n / 2);
  for (let i = half; i < pts.length - (n - 1 - half); i++) {
    const win = pts.slice(i - half, i - half + n);
    const w = win.map((p) => 1 / Math.max(p.stat_err_m, 1e-6) ** 2);
    const sw = w.reduce((a, b) => a + b, 0);
    out.push({
      t_unix_s: win.reduce((a, p, k) => a + w[k] * shipT(p), 0) / sw,
      lambda_att_m: win.reduce((a, p, k) => a + w[k] * p.lambda_att_m, 0) / sw,
      span_s: shipT(win[win.length - 1]) - shipT(win[0]),
    });
  }
  return out;
}

/** Traces of the series against time; with `smoothVisits` > 1, a line of means over that many visits. */
export function timeTraces(series, { smoothVisits = 0 } = {}) {
  const traces = [];
  for (const wl of Object.keys(series || {}).sort()) {
    const pts = (series[wl] || []).filter(hasValue);
    if (!pts.length) continue;
    traces.push(...pointTraces(wl, pts, "time"));
    if (smoothVisits > 1 && pts.length >= smoothVisits) {
      const s = smoothed(pts, smoothVisits);
      const span = s.length ? s.reduce((a, q) => a + q.span_s, 0) / s.length : 0;
      traces.push({
        x: s.map((q) => plotDate(q.t_unix_s)),
        y: s.map((q) => q.lambda_att_m),
        type: "scatter",
        mode: "lines",
        name: `${wl} nm, mean of ${smoothVisits} visits (~${fmt(span / 60, 0)} min)`,
        legendgroup: wl,
        line: { color: wlColor(wl), width: 2, dash: "dot" },
        hovertemplate: `${wl} nm: %{y:.2f} m, mean of ${smoothVisits} visits<extra></extra>`,
      });
    }
  }
  return traces;
}

/** Traces of the profile: λ_att against the LEM's depth, one point per visit. */
export function profileTraces(series) {
  const traces = [];
  for (const wl of Object.keys(series || {}).sort()) {
    const pts = (series[wl] || []).filter((p) => hasValue(p) && p.depth_m !== null && p.depth_m !== undefined);
    if (pts.length) traces.push(...pointTraces(wl, pts, "depth"));
  }
  return traces;
}

/** The depth axis: down, spanning the points (at least 40 m, so one stop is not a line). */
export function profileLayout(series, extra = {}) {
  const depth = { title: { text: "LEM depth (m)" }, autorange: "reversed", tickformat: ",.0f" };
  const ds = Object.values(series || {})
    .flat()
    .filter(hasValue)
    .map((p) => p.depth_m)
    .filter((d) => d !== null && d !== undefined);
  if (ds.length) {
    const lo = Math.min(...ds);
    const hi = Math.max(...ds);
    const pad = Math.max(20 - (hi - lo) / 2, (hi - lo) * 0.06);
    Object.assign(depth, { autorange: false, range: [hi + pad, lo - pad] });
    const stops = depthStops(ds);
    // A few stops (the test stops, the station): a label at each, where the points are, rather than
    // round depths between them (at phone width 1500 m, 2000 m... labelled none of them).
    const text = (d) => String(d).replace(/\B(?=(\d{3})+(?!\d))/g, ","); // 3,420 as the axis writes it
    if (stops.length <= 6) Object.assign(depth, { tickvals: stops, ticktext: stops.map(text) });
  }
  return { xaxis: { title: { text: "λ_att (m)" } }, yaxis: depth, ...extra };
}

/** The depths the points gather at (points within `gapM` of each other are one stop), at their median. */
export function depthStops(depths, gapM = 50) {
  const ds = [...depths].sort((a, b) => a - b);
  const groups = [];
  for (const d of ds) {
    const g = groups[groups.length - 1];
    if (g && d - g[g.length - 1] <= gapM) g.push(d);
    else groups.push([d]);
  }
  return groups.map((g) => Math.round(g[Math.floor(g.length / 2)]));
}

/**
 * Draw the series against time into `timeDiv` and the depth profile into `depthDiv`.
 * @param {object} opts {smoothVisits, uirevision, filename, emptyText}
 */
export function drawVisitSeries(timeDiv, depthDiv, series, opts = {}) {
  const { smoothVisits = 0, uirevision, filename = "camcal-lambda-att", emptyText = "no λ_att point yet" } = opts;
  const has = Object.values(series || {}).some((pts) => pts.some(hasValue));
  const empty = has ? {} : emptyPlot(emptyText);
  const times = Object.values(series || {}).flatMap((pts) => pts.filter(hasValue).map((p) => p.t_unix_s));
  const timeLay = {
    xaxis: timeAxis(times),
    yaxis: { title: { text: "λ_att (m)" } },
    title: { text: "per visit, against time" },
    uirevision,
    ...empty,
  };
  if (smoothVisits > 1) {
    // The smoothed lines' names are long: their legend goes under the plot, clear of the title.
    Object.assign(timeLay, {
      legend: { orientation: "h", x: 0, y: -0.36, yanchor: "top" },
      margin: { l: 60, r: 16, t: 36, b: 140 },
    });
  }
  const depthLay = { ...profileLayout(series, { title: { text: "profile against depth" }, uirevision }), ...empty };
  depthDiv.dataset.points = String(profileTraces(series).reduce((n, t) => n + (t.showlegend === false ? 0 : t.x.length), 0));
  return Promise.all([
    draw(timeDiv, timeTraces(series, { smoothVisits }), timeLay, `${filename}-time`),
    draw(depthDiv, profileTraces(series), depthLay, `${filename}-profile`),
  ]);
}
