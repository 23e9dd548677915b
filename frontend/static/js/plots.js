// plotly.js, loaded on demand from /vendor (never a CDN), styled from the page's theme, and the
// figures both pages draw: radial profiles, linearity, time series (λ_att: lambda-profile.js).

import { WAVELENGTHS, fmt, plotDate, wlColor } from "./format.js";

let loading = null;

/** window.Plotly, loading /vendor/plotly.min.js the first time (it is 4.8 MB: not before it is needed). */
export function loadPlotly() {
  if (window.Plotly) return Promise.resolve(window.Plotly);
  if (!loading) {
    loading = new Promise((resolve, reject) => {
      const s = document.createElement("script");
      s.src = "/vendor/plotly.min.js";
      s.async = true;
      s.onload = () => resolve(window.Plotly);
      s.onerror = () => {
        loading = null;
        reject(new Error("plotly.js could not be loaded from /vendor/plotly.min.js; reload the page"));
      };
      document.head.append(s);
    });
  }
  return loading;
}

function cssVar(name) {
  return getComputedStyle(document.documentElement).getPropertyValue(name).trim();
}

const FONT = 'system-ui, -apple-system, "Segoe UI", Roboto, "Noto Sans", "DejaVu Sans", sans-serif';

function axis(extra = {}) {
  const line = cssVar("--line");
  return { gridcolor: line, zerolinecolor: line, linecolor: line, automargin: true, ...extra };
}

/** A layout in the theme's colours (opaque, so a downloaded PNG reads as it does on screen). */
export function layout(extra = {}) {
  const { xaxis, yaxis, title, ...rest } = extra;
  return {
    // The title on the right, the legend on the left: both fit above the plot.
    title: title ? { x: 0.995, xanchor: "right", font: { size: 14 }, ...title } : undefined,
    paper_bgcolor: cssVar("--panel"),
    plot_bgcolor: cssVar("--panel"),
    font: { color: cssVar("--fg"), family: FONT, size: 13 },
    margin: { l: 60, r: 16, t: 36, b: 48 },
    legend: { orientation: "h", x: 0, y: 1.02, yanchor: "bottom", bgcolor: "rgba(0,0,0,0)" },
    hovermode: "closest",
    hoverlabel: { font: { family: FONT } },
    xaxis: axis(xaxis),
    yaxis: axis(yaxis),
    ...rest,
  };
}

export function plotConfig(filename, extra = {}) {
  return {
    displaylogo: false,
    responsive: true,
    toImageButtonOptions: { format: "png", filename, scale: 2 },
    modeBarButtonsToRemove: ["lasso2d", "select2d", "autoScale2d"],
    ...extra,
  };
}

/**
 * On a narrow figure (a phone) the legend wraps to two rows and ran into the title on its right:
 * the title goes on a line of its own above the legend.
 */
function narrowed(div, lay) {
  if (!lay?.title || !div.clientWidth || div.clientWidth >= 560) return lay;
  const t = Math.max(lay.margin?.t ?? 36, 84);
  return {
    ...lay,
    title: { ...lay.title, x: 0.01, xanchor: "left", y: 0.99, yanchor: "top", yref: "container" },
    margin: { l: 60, r: 16, b: 48, ...(lay.margin || {}), t },
  };
}

/** Whether a figure's div is phone-narrow: its legend, ticks and height adapt. */
export function isNarrow(div) {
  return Boolean(div?.clientWidth) && div.clientWidth < 560;
}

const HOUR_MS = 3600e3;

/**
 * A UTC time axis whose ticks say the time of day only and whose title says the date: plotly's own
 * date line under the first tick ran over the tick labels on a phone. Over several days the ticks
 * carry the day too.
 */
export function timeAxis(times, extra = {}) {
  let lo = Infinity;
  let hi = -Infinity;
  for (const t of times || []) {
    if (Number.isFinite(t)) {
      lo = Math.min(lo, t);
      hi = Math.max(hi, t);
    }
  }
  const day = (t) => new Date(t * 1000).toISOString().slice(0, 10);
  const days = lo <= hi ? [day(lo), day(hi)] : [];
  const when = !days.length ? "" : days[0] === days[1] ? `, ${days[0]}` : `, ${days[0]} to ${days[1]}`;
  const clock = days.length && days[0] !== days[1] ? "%d %b %H:%M" : "%H:%M";
  return {
    type: "date",
    title: { text: `time (UTC${when})` },
    tickformatstops: [
      { dtickrange: [null, 1000], value: "%H:%M:%S.%L" },
      { dtickrange: [1000, 60e3], value: "%H:%M:%S" },
      { dtickrange: [60e3, 12 * HOUR_MS], value: clock },
      { dtickrange: [12 * HOUR_MS, null], value: "%d %b" },
    ],
    ...extra,
  };
}

/** Draw (or redraw in place) a figure; resolves once plotly has drawn it. */
export async function draw(div, traces, lay, filename, config = {}) {
  const Plotly = await loadPlotly();
  await Plotly.react(div, traces, layout(narrowed(div, lay)), plotConfig(filename, config));
  div.dataset.drawn = "1";
  return div;
}

/** Layout parts for a figure with nothing to show yet: no axes, one line of text. */
export function emptyPlot(text) {
  return {
    xaxis: { visible: false },
    yaxis: { visible: false },
    annotations: [{ text, showarrow: false, xref: "paper", yref: "paper", x: 0.5, y: 0.5, font: { size: 15 } }],
  };
}

export function purge(div) {
  if (window.Plotly && div) window.Plotly.purge(div);
}

// ------------------------------------------------------------------ radial profile
/** The radial band profile (log y) with its exponential + constant fit and the background. */
export function profileFigure(frame, { narrow = false } = {}) {
  const p = frame.profile;
  const f = frame.fit;
  const traces = [];
  if (p && p.radius_px?.length) {
    traces.push({
      x: p.radius_px,
      y: p.mean_gray,
      error_y: { type: "data", array: p.sem_gray, visible: true, thickness: 1, width: 0 },
      type: "scatter",
      mode: "markers",
      marker: { size: 4, color: cssVar("--accent") },
      name: "mean gray per band",
    });
  }
  const shapes = [];
  if (f && f.amplitude_gray !== null && f.scale_px) {
    const rMax = p?.radius_px?.length ? p.radius_px[p.radius_px.length - 1] : 150;
    const rMin = f.r_min_px ?? 0;
    const model = (r) => f.amplitude_gray * Math.exp(-r / f.scale_px) + f.background_gray;
    const xs = [];
    for (let r = rMin; r <= rMax; r += Math.max(0.5, (rMax - rMin) / 200)) xs.push(r);
    traces.push({
      x: xs,
      y: xs.map(model),
      type: "scatter",
      mode: "lines",
      line: { color: cssVar("--minor"), width: 2.5 },
      name: `fit: ${fmt(f.amplitude_gray, 1)}·exp(−r/${fmt(f.scale_px, 1)} px) + ${fmt(f.background_gray, 2)}`,
    });
    traces.push({
      x: [0, rMax],
      y: [f.background_gray, f.background_gray],
      type: "scatter",
      mode: "lines",
      line: { color: cssVar("--ok"), width: 1.5, dash: "dash" },
      name: `background ${fmt(f.background_gray, 2)} gray`,
    });
    shapes.push(vline(rMin, cssVar("--muted"), "dot"));
  }
  if (frame.radius_px) shapes.push(vline(frame.radius_px, cssVar("--major"), "dash"));
  return {
    traces,
    layout: {
      xaxis: { title: { text: "radius (px)" } },
      yaxis: { title: { text: "mean gray" }, type: "log" },
      // In the corner where the profile has fallen to its background; on a phone that corner is the
      // data's, and the legend goes under the figure.
      legend: narrow
        ? { orientation: "v", x: 0, xanchor: "left", y: -0.3, yanchor: "top" }
        : { x: 0.99, xanchor: "right", y: 0.99, yanchor: "top", bgcolor: cssVar("--panel-2"), bordercolor: cssVar("--line"), borderwidth: 1 },
      ...(narrow ? { margin: { l: 60, r: 16, t: 84, b: 150 } } : {}),
      shapes,
      annotations: frame.radius_px
        ? [{ x: frame.radius_px, y: 1, yref: "paper", text: "LEM disk", showarrow: false, yanchor: "bottom" }]
        : [],
    },
  };
}

function vline(x, color, dash) {
  return { type: "line", x0: x, x1: x, y0: 0, y1: 1, yref: "paper", line: { color, width: 1.5, dash } };
}

// ------------------------------------------------------------------ linearity
/**
 * One module's linearity checks for one sweep (exposure or gain), on log-log axes: the points
 * (open: outside the linear range, left out of the fit), the straight-line fit, the knee.
 */
/**
 * Of the ticks of a log axis, those whose labels have room: each at least `labelPx` from the last one
 * kept, on an axis `widthPx` wide (the smallest and the largest are kept first).
 */
export function spacedTicks(values, widthPx, labelPx = 44) {
  const vals = [...values].filter((v) => v > 0).sort((a, b) => a - b);
  if (vals.length < 3 || !widthPx) return vals;
  const span = Math.log10(vals[vals.length - 1] / vals[0]) || 1;
  const perDecade = (widthPx * 0.9) / span; // plotly pads a log axis a little on each side
  const kept = [vals[0]];
  const last = vals[vals.length - 1];
  for (const v of vals.slice(1, -1)) {
    const room = (a, b) => Math.log10(b / a) * perDecade >= labelPx;
    if (room(kept[kept.length - 1], v) && room(v, last)) kept.push(v);
  }
  kept.push(last);
  return kept;
}

/** The linearity figure of one sweep; `plotWidthPx` (the div's width) thins its ticks to what fits. */
export function linearityFigure(checks, sweep, plotWidthPx = 0) {
  const traces = [];
  const shapes = [];
  const ticks = new Set();
  for (const c of checks) {
    const color = wlColor(c.wavelength_nm);
    const { x, gray, used } = c.points || { x: [], gray: [], used: [] };
    x.forEach((v) => ticks.add(v));
    const pick = (flag) => x.map((_, i) => i).filter((i) => Boolean(used[i]) === flag);
    const inR = pick(true);
    const outR = pick(false);
    const r2 = c.r2 === null ? "–" : c.r2.toFixed(4);
    const group = String(c.wavelength_nm);
    traces.push({
      x: inR.map((i) => x[i]),
      y: inR.map((i) => gray[i]),
      type: "scatter",
      mode: "markers",
      marker: { color, size: 8 },
      name: `${c.wavelength_nm} nm · R² ${r2}`,
      legendgroup: group,
    });
    if (outR.length) {
      traces.push({
        x: outR.map((i) => x[i]),
        y: outR.map((i) => gray[i]),
        type: "scatter",
        mode: "markers",
        marker: { color, size: 9, symbol: "circle-open", line: { width: 2 } },
        name: `${c.wavelength_nm} nm outside linear range`,
        legendgroup: group,
        showlegend: false,
      });
    }
    if (c.slope !== null && x.length) {
      const lo = Math.min(...x);
      const hi = Math.max(...x);
      const xs = [];
      for (let i = 0; i <= 60; i++) xs.push(lo * Math.pow(hi / lo, i / 60));
      const fit = xs.map((v) => c.slope * v + c.intercept_gray);
      const keep = xs.map((_, i) => i).filter((i) => fit[i] > 0 && fit[i] <= 300);
      traces.push({
        x: keep.map((i) => xs[i]),
        y: keep.map((i) => fit[i]),
        type: "scatter",
        mode: "lines",
        line: { color, width: 1.5, dash: "dot" },
        name: `${c.wavelength_nm} nm fit`,
        legendgroup: group,
        showlegend: false,
        hoverinfo: "skip",
      });
    }
    if (c.knee_x) shapes.push({ ...vline(c.knee_x, color, "dash"), line: { color, width: 2, dash: "dash" } });
  }
  const tickvals = spacedTicks(ticks, plotWidthPx ? plotWidthPx - 76 : 0);
  const ticktext = tickvals.map((v) => (sweep === "exposure" ? `${v}` : `${Math.round(20 * Math.log10(v))} dB`));
  return {
    traces,
    layout: {
      xaxis: {
        title: { text: sweep === "exposure" ? "exposure (s)" : "gain (its linear factor on a log scale)" },
        type: "log",
        tickvals,
        ticktext,
        tickangle: 0,
      },
      // 255 is the clipping line's own label: a tick beside 200 would run into it
      yaxis: { title: { text: "centre gray" }, type: "log", tickvals: [5, 10, 20, 50, 100, 200] },
      shapes: [
        ...shapes,
        { type: "line", x0: 0, x1: 1, xref: "paper", y0: 255, y1: 255, line: { color: cssVar("--major"), width: 1 } },
      ],
      annotations: [
        { x: 1, xref: "paper", xanchor: "right", y: Math.log10(255), yanchor: "bottom", text: "255: clipped", showarrow: false, font: { size: 11, color: cssVar("--major") } },
      ],
    },
  };
}

// ------------------------------------------------------------------ time series
/**
 * Stacked panels sharing one time axis.
 * @param {Array<{title: string, series: Array<{name, t, y, color, dash}>}>} panels
 */
export function stackedFigure(panels) {
  const traces = [];
  const lay = { grid: { rows: panels.length, columns: 1, pattern: "coupled", ygap: 0.12 }, showlegend: true };
  panels.forEach((panel, i) => {
    const ax = i === 0 ? "" : String(i + 1);
    lay[`yaxis${ax}`] = axis({ title: { text: panel.title } });
    for (const s of panel.series) {
      traces.push({
        x: s.t.map(plotDate),
        y: s.y,
        type: "scatter",
        mode: "lines",
        name: s.name,
        legendgroup: s.name,
        showlegend: i === 0,
        line: { color: s.color, width: s.width || 1.5, dash: s.dash || "solid" },
        xaxis: "x",
        yaxis: `y${ax}`,
      });
    }
  });
  lay.xaxis = timeAxis(panels.flatMap((p) => p.series.flatMap((s) => [s.t[0], s.t[s.t.length - 1]])));
  return { traces, layout: lay };
}

export { WAVELENGTHS };
