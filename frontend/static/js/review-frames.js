// Review: the dive's timeline (depth, frames, alarms; click to jump), the frame browser with its
// filters and pages, and one frame opened in full with its radial profile and background fit.

import { api, query } from "./api.js";
import { REASONS, fmt, fmtExposure, fromLocalInput, fromPlotDate, plotDate, utc } from "./format.js";
import { drawOverlay } from "./live-cards.js";
import { draw, emptyPlot, isNarrow, profileFigure, timeAxis } from "./plots.js";
import { $, el, lrm, setText, toast } from "./ui.js";

const MODULE_COLORS = ["#5cc8ff", "#ff9f43", "#c46bff", "#52e07a"];
const SEV_COLORS = { MAJOR: "#ff4d4d", MINOR: "#ffb020" };

const view = { ctx: null, offset: 0, total: 0, items: [], markT: null, selectedId: null, timeline: null, clickBound: false };

function form() {
  return $("#frame-filters");
}

/** The filters as API parameters (time inputs are UTC). */
function filters() {
  const f = form();
  const status = f.status.value;
  const isReason = REASONS.includes(status);
  return {
    dive: view.ctx.dive.id,
    module: f.module.value,
    wavelength_nm: f.wavelength_nm.value,
    exposure_s: f.exposure_s.value,
    gain_db: f.gain_db.value,
    status: isReason ? "rejected" : status,
    reason: isReason ? status : "",
    t_from: fromLocalInput(f.t_from.value),
    t_to: fromLocalInput(f.t_to.value),
    depth_min_m: f.depth_min_m.value,
    depth_max_m: f.depth_max_m.value,
    order: f.order.value,
    limit: Number(f.limit.value),
  };
}

function fillSelect(select, values, label = (v) => String(v)) {
  const keep = select.value;
  select.replaceChildren(el("option", { value: "" }, "any"), ...values.map((v) => el("option", { value: v }, label(v))));
  if ([...select.options].some((o) => o.value === keep)) select.value = keep;
}

/** Set the filter menus from the dive's settings and wire the form (once). */
function setupForm(ctx) {
  const f = form();
  const s = ctx.settings || {};
  fillSelect(f.module, s.modules || [], (m) => `${lrm(m)}`);
  fillSelect(f.wavelength_nm, s.wavelengths_nm || [], (w) => `${w} nm`);
  fillSelect(f.exposure_s, s.exposures_s || [], fmtExposure);
  fillSelect(f.gain_db, s.gains_db || [], (g) => `${fmt(g, 0)} dB`);
  if (!f.status.querySelector('[value="saturated"]')) {
    f.status.append(...REASONS.map((r) => el("option", { value: r }, `rejected: ${r.replace("_", " ")}`)));
  }
  if (f.dataset.wired) return;
  f.dataset.wired = "1";
  let timer = null;
  const changed = () => {
    clearTimeout(timer);
    timer = setTimeout(() => {
      view.offset = 0;
      view.markT = null;
      load();
    }, 250);
  };
  f.addEventListener("change", changed);
  f.addEventListener("input", (ev) => ev.target.type === "number" && changed());
  f.addEventListener("reset", () => setTimeout(changed, 0));
  f.addEventListener("submit", (ev) => ev.preventDefault());
  $("#page-prev").addEventListener("click", () => {
    view.offset = Math.max(0, view.offset - filters().limit);
    load();
  });
  $("#page-next").addEventListener("click", () => {
    view.offset += filters().limit;
    load();
  });
}

export async function showFrames(ctx) {
  view.ctx = ctx;
  view.offset = 0;
  view.markT = null;
  $("#frame-detail").hidden = true;
  setupForm(ctx);
  await Promise.all([drawTimeline(), load()]);
}

// ------------------------------------------------------------------ the list
async function load() {
  const p = filters();
  const tbody = $("#frames-table tbody");
  tbody.setAttribute("aria-busy", "true");
  let page;
  try {
    page = await api(`/api/frames${query({ ...p, offset: view.offset })}`);
  } catch (err) {
    toast(err.message);
    tbody.removeAttribute("aria-busy");
    return;
  }
  view.items = page.items;
  view.total = page.total;
  tbody.removeAttribute("aria-busy");
  const marked = markedIndex(page.items);
  tbody.replaceChildren(
    ...page.items.map((fr, i) =>
      el(
        "tr",
        {
          class: `clickable${fr.id === view.selectedId ? " selected" : ""}${i === marked ? " marked" : ""}`,
          "data-frame-id": fr.id,
          tabindex: "0",
          onclick: () => openFrame(fr.id),
          onkeydown: (ev) => ev.key === "Enter" && openFrame(fr.id),
        },
        el("td", {}, el("img", { class: "mini", src: fr.thumbnail_url, alt: "", loading: "lazy", width: 62, height: 52 })),
        el("td", { class: "r" }, fr.id),
        // when it was taken on the ship's clock (the dive's one axis); its module's own in the tooltip
        ((stamp) =>
          el(
            "td",
            { title: `${stamp} on the ship's clock; ${utc(fr.captured_unix_s)} on module ${fr.module}'s` },
            el("span", { class: "date" }, `${stamp.slice(0, 10)} `),
            stamp.slice(11),
          ))(utc(shipTime(fr))),
        el("td", {}, fr.module),
        el("td", { class: "r" }, `${fr.wavelength_nm} nm`),
        el("td", { class: "r" }, fmtExposure(fr.exposure_s)),
        el("td", { class: "r" }, `${fmt(fr.gain_db, 0)} dB`),
        el("td", { class: "r" }, fr.depth_m === null ? "–" : `${fmt(fr.depth_m, 0)} m`),
        el("td", { class: `status-${fr.status} status-cell` }, fr.status === "rejected" ? `rejected: ${fr.reason}` : fr.status),
        el(
          "td",
          { class: "r" },
          fr.i_center_gray === null ? "–" : [`${fmt(fr.i_center_gray, 2)} `, el("span", { class: "pm" }, `± ${fmt(fr.i_center_err_gray, 2)}`)],
        ),
        el("td", { class: "r col-background" }, fmt(fr.background_gray, 2)),
      ),
    ),
  );
  if (!page.items.length) tbody.append(el("tr", {}, el("td", { colspan: 11, class: "empty" }, "No frames match these filters.")));
  const lo = page.total ? view.offset + 1 : 0;
  const hi = Math.min(view.offset + page.items.length, page.total);
  setText($("#page-info"), `${lo}–${hi} of ${page.total} frames · page ${Math.floor(view.offset / p.limit) + 1} of ${Math.max(1, Math.ceil(page.total / p.limit))}`);
  $("#page-prev").disabled = view.offset === 0;
  $("#page-next").disabled = view.offset + p.limit >= page.total;
  if (marked >= 0) tbody.children[marked].scrollIntoView({ block: "nearest" });
}

/** When a frame was taken on the ship's clock (its module's, mapped: `camcal.core.clockmap`). */
const shipTime = (fr) => fr.captured_ship_unix_s ?? fr.captured_unix_s;

/** The row nearest the time picked on the timeline. */
function markedIndex(items) {
  if (view.markT === null || !items.length) return -1;
  let best = 0;
  items.forEach((fr, i) => {
    if (Math.abs(shipTime(fr) - view.markT) < Math.abs(shipTime(items[best]) - view.markT)) best = i;
  });
  return best;
}

/** Jump the list to the page holding time t (other filters kept, time range cleared). */
export async function jumpTo(t) {
  const f = form();
  f.t_from.value = "";
  f.t_to.value = "";
  const p = filters();
  const before = p.order === "newest" ? { t_from: t + 1e-3 } : { t_to: t - 1e-3 };
  try {
    const n = (await api(`/api/frames${query({ ...p, ...before, limit: 1, offset: 0 })}`)).total;
    view.offset = Math.floor(n / p.limit) * p.limit;
  } catch (err) {
    toast(err.message);
    return;
  }
  view.markT = t;
  markTimeline(t);
  await load();
  $("#frame-browser").scrollIntoView({ block: "start", behavior: "smooth" });
}

// ------------------------------------------------------------------ the timeline
async function drawTimeline() {
  const div = $("#timeline");
  let tl;
  try {
    tl = await api(`/api/dives/${view.ctx.dive.id}/timeline`);
  } catch (err) {
    toast(err.message);
    return;
  }
  view.timeline = tl;
  setText($("#timeline-clocks"), clocksNote(tl.clocks || []));
  const traces = [];
  const modules = [...new Set(tl.frames.map((f) => f.module))].sort();
  // each module's own depth (they hang ~20 m apart: one line of both zigzagged between them)
  modules.forEach((m, i) => {
    const depth = tl.depth_by_module?.[m];
    if (!depth?.t_unix_s.length) return;
    traces.push({
      x: depth.t_unix_s.map(plotDate),
      y: depth.depth_m,
      type: "scatter",
      mode: "lines",
      name: `depth ${lrm(m)} (sensors)`,
      line: { color: MODULE_COLORS[i % MODULE_COLORS.length], width: 1.5, dash: i ? "dot" : "solid" },
      hovertemplate: `${lrm(m)} %{x}<br>%{y:.0f} m<extra></extra>`,
    });
  });
  // The later modules' frames first, under the first module's: LRM-A's dots lie on LRM-B's hollow
  // diamonds (they take frames at the same moments), each visible (legendrank keeps A first).
  const frameTraces = modules.map((m, i) => {
    const fs = tl.frames.filter((f) => f.module === m);
    return {
      x: fs.map((f) => plotDate(f.t_unix_s)),
      y: fs.map((f) => f.depth_m),
      customdata: fs.map((f) => f.id),
      type: "scatter",
      mode: "markers",
      name: `frames ${lrm(m)}`,
      legendrank: 1001 + i,
      marker: i
        ? { size: 9, color: MODULE_COLORS[i % MODULE_COLORS.length], symbol: "diamond-open", line: { width: 1.5 } }
        : { size: 5, color: MODULE_COLORS[0], symbol: "circle" },
      hovertemplate: `${lrm(m)} frame #%{customdata}<br>%{x}<br>%{y:.0f} m<extra></extra>`,
    };
  });
  traces.push(...frameTraces.reverse());
  if (tl.alarms.length) {
    traces.push({
      x: tl.alarms.map((a) => plotDate(a.raised_unix_s)),
      y: tl.alarms.map(() => 0),
      text: tl.alarms.map((a) => `${a.severity} ${a.module ? `${lrm(a.module)} ` : ""}${a.message}`),
      type: "scatter",
      mode: "markers",
      name: "alarms",
      legendrank: 1100,
      marker: { size: 13, symbol: "triangle-down", color: tl.alarms.map((a) => SEV_COLORS[a.severity] || "#999") },
      hovertemplate: "%{text}<br>%{x}<extra></extra>",
    });
  }
  const lay = {
    xaxis: timeAxis([...tl.frames.map((f) => f.t_unix_s), ...Object.values(tl.depth_by_module || {}).flatMap((d) => d.t_unix_s)]),
    yaxis: { title: { text: "depth (m)" }, autorange: "reversed" },
    margin: { l: 60, r: 16, t: 30, b: 44 },
    height: isNarrow(div) ? 400 : 280, // on a phone its legend takes four lines above the plot
    shapes: [],
    uirevision: view.ctx.dive.id,
  };
  if (!traces.length) Object.assign(lay, emptyPlot("no depth or frames in this dive yet"));
  await draw(div, traces, lay, `camcal-${view.ctx.dive.name}-timeline`);
  if (!view.clickBound) {
    view.clickBound = true;
    div.on("plotly_click", (ev) => {
      const pt = ev.points && ev.points[0];
      if (!pt) return;
      const t = fromPlotDate(pt.x);
      jumpTo(t);
      if (typeof pt.customdata === "number") openFrame(pt.customdata);
    });
  }
}

/**
 * How each module's clock lies on the ship's, the axis every time of the page is drawn on: a
 * simulated clock's rate and when it was mapped, a real one's offset as measured at its heartbeats.
 */
export function clocksNote(clocks) {
  if (!clocks.length) return "Times on the ship's clock.";
  const off = (c) => (c.offset_s === null ? "offset not measured yet" : `${c.offset_s >= 0 ? "+" : "−"}${fmt(Math.abs(c.offset_s), 2)} s`);
  const parts = clocks.map((c) =>
    c.rate !== 1
      ? `${lrm(c.module)}: a simulated clock at ${fmt(c.rate, 0)}×, mapped onto the ship's from ${utc(c.first_unix_s, { date: false })} UTC (offset ${off(c)})`
      : `${lrm(c.module)}: clock ${off(c)} against the ship's (at ${utc(c.updated_unix_s, { date: false })} UTC)`,
  );
  return `Times on the ship's clock; the modules' mapped onto it at the handshake and every heartbeat. ${parts.join("; ")}.`;
}

function markTimeline(t) {
  const div = $("#timeline");
  if (!window.Plotly || !div.dataset.drawn) return;
  window.Plotly.relayout(div, {
    shapes: [{ type: "line", x0: plotDate(t), x1: plotDate(t), y0: 0, y1: 1, yref: "paper", line: { color: "#ffd84d", width: 2 } }],
  });
}

// ------------------------------------------------------------------ one frame
function frameParam(id) {
  const p = new URLSearchParams(location.hash.slice(1));
  if (id === null) p.delete("frame");
  else p.set("frame", id);
  history.replaceState(null, "", `#${p}`);
}

export async function openFrame(id) {
  view.selectedId = id;
  frameParam(id);
  for (const tr of document.querySelectorAll("#frames-table tbody tr")) {
    tr.classList.toggle("selected", Number(tr.dataset.frameId) === id);
  }
  const box = $("#frame-detail");
  box.hidden = false;
  box.replaceChildren(el("p", { class: "muted" }, `loading frame #${id}…`));
  let fr;
  try {
    fr = await api(`/api/frames/${id}`);
  } catch (err) {
    box.replaceChildren(el("p", { class: "error-msg" }, err.message));
    return;
  }
  const svg = document.createElementNS("http://www.w3.org/2000/svg", "svg");
  const img = el("img", { src: fr.image_url, alt: `frame ${fr.id}, full resolution`, id: "frame-image" });
  const idx = view.items.findIndex((f) => f.id === id);
  const nav = (d) => {
    const next = view.items[idx + d];
    if (next) openFrame(next.id);
  };
  const profileDiv = el("div", { id: "profile-plot", class: "plot tall" });
  box.replaceChildren(
    el(
      "div",
      { class: "card-head" },
      el("h2", { style: { margin: 0 } }, `Frame #${fr.id} · ${lrm(fr.module)} · ${utc(shipTime(fr), { ms: true })}`),
      el("span", { class: "spacer", style: { flex: 1 } }),
      el("button", { type: "button", disabled: idx <= 0, onclick: () => nav(-1) }, "← Previous frame"),
      el("button", { type: "button", disabled: idx < 0 || idx >= view.items.length - 1, onclick: () => nav(1) }, "Next frame →"),
      el(
        "button",
        {
          type: "button",
          "aria-pressed": "false",
          title: "display only: multiply the gray values by 4 to see the halo and the background",
          onclick: (ev) => {
            const on = img.classList.toggle("brighten");
            ev.currentTarget.setAttribute("aria-pressed", String(on));
          },
        },
        "Brighten ×4",
      ),
      el("a", { class: "button", href: fr.image_url, target: "_blank", rel: "noopener" }, "Open full PNG"),
      el("button", { type: "button", onclick: () => ((box.hidden = true), frameParam(null)) }, "Close"),
    ),
    el(
      "div",
      { class: "frame-detail" },
      el("div", {}, el("div", { class: "thumb", style: { aspectRatio: `${fr.width_px} / ${fr.height_px}` } }, img, svg), numbers(fr)),
      el("div", {}, profileDiv),
    ),
  );
  drawOverlay(svg, fr);
  box.scrollIntoView({ block: "start", behavior: "smooth" });
  if (fr.profile) {
    const fig = profileFigure(fr, { narrow: isNarrow(profileDiv) });
    await draw(profileDiv, fig.traces, { ...fig.layout, title: { text: `frame #${fr.id}: radial profile and background fit` } }, `camcal-frame-${fr.id}-profile`);
  } else {
    profileDiv.replaceChildren(el("p", { class: "empty" }, fr.status === "pending" ? "not analysed yet" : `no profile: ${fr.reason || "rejected"}${fr.detail ? ` — ${fr.detail}` : ""}`));
  }
}

function numbers(fr) {
  const pm = (v, e, d = 2) => (v === null || v === undefined ? "–" : `${fmt(v, d)}${e !== null && e !== undefined ? ` ± ${fmt(e, d)}` : ""} gray`);
  const fit = fr.fit || {};
  const rows = [
    ["status", fr.status === "rejected" ? `rejected: ${fr.reason}` : fr.status],
    ["detail", fr.detail || "–"],
    ["setting", `${fr.wavelength_nm} nm · ${fmtExposure(fr.exposure_s)} · ${fmt(fr.gain_db, 0)} dB`],
    ["depth", fr.depth_m === null ? "–" : `${fmt(fr.depth_m, 1)} m`],
    // the dive's one clock (the ship's), and the module's own as it stamped the frame
    ["taken", `${utc(shipTime(fr), { ms: true })} UTC, ship's clock`],
    ["module's clock", `${utc(fr.captured_unix_s, { ms: true })} UTC`],
    ["received", fr.received_unix_s ? `${utc(fr.received_unix_s, { ms: true })} UTC` : "–"],
    ["size", `${fr.width_px} × ${fr.height_px} px`],
    ["centroid (x, y)", fr.centroid_px ? `${fmt(fr.centroid_px[0], 2)}, ${fmt(fr.centroid_px[1], 2)} px` : "–"],
    ["LEM radius", fr.radius_px === null ? "–" : `${fmt(fr.radius_px, 1)} px`],
    ["elongation", fmt(fr.elongation, 3)],
    ["centre", pm(fr.center_gray, fr.center_err_gray)],
    ["background", pm(fr.background_gray, fr.background_err_gray)],
    ["I_center", pm(fr.i_center_gray, fr.i_center_err_gray)],
    ["fit", fit.scale_px ? `A ${fmt(fit.amplitude_gray, 1)} gray, scale ${fmt(fit.scale_px, 1)} px, r ≥ ${fmt(fit.r_min_px, 0)} px` : "–"],
    ["fit χ²/ndof", fit.chi2_ndof === undefined ? "–" : `${fmt(fit.chi2_ndof, 2)}${fit.converged === false ? " (not converged)" : ""}`],
    ["sequence", `${fr.boot} / ${fr.seq}`],
    ["sha256", fr.sha256 ? `${fr.sha256.slice(0, 16)}…` : "–"],
  ];
  return el("dl", { class: "kv", id: "frame-numbers", style: { marginTop: "0.6rem" } }, ...rows.flatMap(([k, v]) => [el("dt", {}, k), el("dd", {}, v)]));
}
