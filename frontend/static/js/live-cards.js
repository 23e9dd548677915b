// The live view's module card: link and age, the latest thumbnail with the detected LEM drawn on it,
// the camera's current setting, depth and phase, attitude and housing, frame quality.

import { fmt, fmtAge, fmtExposure, qualityClass, qualityKey, qualityLabel, utc } from "./format.js";
import { el, lrm, setText } from "./ui.js";

const SVG = "http://www.w3.org/2000/svg";

function svg(tag, attrs) {
  const n = document.createElementNS(SVG, tag);
  for (const [k, v] of Object.entries(attrs)) n.setAttribute(k, v);
  return n;
}

function metric(label, field, unit) {
  return el(
    "div",
    { class: "metric" },
    el("div", { class: "label" }, label),
    el("div", { class: "value" }, el("span", { "data-field": field }, "–"), el("span", { class: "unit" }, unit)),
  );
}

/**
 * Draw the detected LEM (circle and centroid cross) over an image of a frame.
 * The SVG's viewBox is the frame in pixels, so it scales with the picture; a point (x, y) has its
 * origin at the centre of the top-left pixel (docs/conventions.md), i.e. at (0.5, 0.5) in the box.
 */
export function drawOverlay(svgEl, frame) {
  const w = frame.width_px || 1;
  const h = frame.height_px || 1;
  svgEl.setAttribute("viewBox", `0 0 ${w} ${h}`);
  svgEl.replaceChildren();
  if (!frame.centroid_px) return;
  const cx = frame.centroid_px[0] + 0.5;
  const cy = frame.centroid_px[1] + 0.5;
  const r = frame.radius_px || 0;
  const s = Math.max(w, h) * 0.025;
  if (r > 0) svgEl.append(svg("circle", { class: "overlay-circle", cx, cy, r }));
  svgEl.append(svg("line", { class: "overlay-cross", x1: cx - s, y1: cy, x2: cx + s, y2: cy }));
  svgEl.append(svg("line", { class: "overlay-cross", x1: cx, y1: cy - s, x2: cx, y2: cy + s }));
}

function field(label, value) {
  return el("div", { class: "field" }, el("div", { class: "label" }, label), value);
}

export function createCard(mid) {
  const svgEl = document.createElementNS(SVG, "svg");
  svgEl.setAttribute("aria-hidden", "true");
  const card = el(
    "section",
    { class: "panel module-card", id: `module-${mid}`, "data-module": mid, "aria-label": `module ${mid}` },
    el(
      "div",
      { class: "card-head" },
      el("h2", {}, `${lrm(mid)} `, el("span", { class: "dist", "data-field": "distance" })),
      el("span", { class: "pill sev-INVALID", "data-field": "severity" }, "INVALID"),
      el("span", { class: "link-state", "data-field": "link", "data-link": "unknown" }, "link –"),
      el(
        "a",
        { class: "control-link", href: `/control#module=${encodeURIComponent(mid)}`, title: `${lrm(mid)}'s schedule and commands (control page)` },
        el("span", { "data-field": "schedule" }),
        " ▸",
      ),
    ),
    el("div", { class: "stale-note", "data-field": "stale" }),
    el(
      "div",
      { class: "setting", "aria-label": "current camera setting, depth and phase" },
      field("wavelength", el("span", { class: "wl-chip", "data-field": "wavelength" }, "– nm")),
      field("exposure", el("span", { class: "big", "data-field": "exposure" }, "–")),
      field("gain", el("span", { class: "big", "data-field": "gain" }, "–")),
      field("depth", el("span", { class: "big" }, el("span", { "data-field": "depth" }, "–"), el("span", { class: "unit" }, "m"))),
      field("phase", el("span", { class: "big", "data-field": "phase" }, "–")),
    ),
    el(
      "div",
      { class: "card-body" },
      el(
        "div",
        { class: "thumb", "data-field": "thumb" },
        el("div", { class: "no-frame" }, "no frame yet"),
        svgEl,
        el("span", { class: "overlay-label", "data-field": "frame-label", hidden: true }),
      ),
      el(
        "div",
        {},
        el(
          "dl",
          { class: "kv" },
          el("dt", {}, "last frame"),
          el("dd", {}, el("span", { "data-field": "frame-status" }, "–"), el("span", { class: "muted", "data-field": "frame-age" })),
          el("dt", {}, "I_center"),
          el("dd", { "data-field": "icenter" }, "–"),
          el("dt", { title: "frames the ship received from this module in the last 60 s" }, "frames, last min"),
          el("dd", { "data-field": "frames-min" }, "–"),
        ),
        el(
          "div",
          { class: "metrics" },
          metric("tilt", "tilt", "°"),
          metric("rotation", "rotation", "°/s"),
          metric("heave period", "heave", "s"),
          metric("housing", "temperature", "°C"),
          metric("humidity", "humidity", "%"),
          metric("sensors", "sensor-age", "ago"),
        ),
      ),
    ),
    el(
      "div",
      { class: "quality" },
      el("div", { class: "muted", style: { fontSize: "0.85rem" } }, "frame quality (this dive)"),
      el("div", { class: "qbar", "data-field": "qbar" }),
      el("div", { class: "qlegend", "data-field": "qlegend" }),
      el(
        "div",
        { class: "recent-row" },
        el("span", { class: "muted recent-label" }, "latest frames"),
        el("div", { class: "recent-strip", "data-field": "recent", title: "the latest frames, newest right" }),
        el("span", { class: "muted recent-label" }, "now"),
      ),
    ),
  );
  card.svg = svgEl;
  return card;
}

const f = (card, name) => card.querySelector(`[data-field="${name}"]`);

/** Put a loaded thumbnail (an <img> already decoded) and its overlay in the card. */
export function showThumbnail(card, img, frame) {
  const box = f(card, "thumb");
  box.querySelector("img")?.remove();
  box.querySelector(".no-frame")?.remove();
  img.alt = `module ${card.dataset.module} frame ${frame.id}`;
  img.dataset.frameId = frame.id;
  box.prepend(img);
  if (frame.width_px && frame.height_px) box.style.aspectRatio = `${frame.width_px} / ${frame.height_px}`;
  drawOverlay(card.svg, frame);
  const label = f(card, "frame-label");
  label.hidden = false;
  const st = frame.status === "rejected" && frame.reason ? qualityLabel(qualityKey(frame), { bare: true }) : frame.status;
  // when it was taken on the ship's clock (a simulated module's own runs 10x ahead)
  const taken = frame.captured_ship_unix_s ?? frame.captured_unix_s;
  setText(label, `#${frame.id} · ${utc(taken, { date: false })} · ${st}`);
}

/** Refresh every number of a card from the module's state (cheap: text is set only when it changes). */
export function updateCard(card, m, { now, staleAfter, severity }) {
  const age = m.lastPacketAt === null ? null : (now - m.lastPacketAt) / 1000;
  const stale = age === null || age > staleAfter;
  card.classList.toggle("stale", stale);
  setText(f(card, "stale"), stale ? `INVALID — no data from ${lrm(m.id)} for ${fmtAge(age)} (stale after ${staleAfter} s)` : "");
  setText(f(card, "distance"), m.distance_m ? `${fmt(m.distance_m, 2)} m from the LEM` : "");
  const sev = f(card, "severity");
  sev.className = `pill sev-${severity}`;
  setText(sev, severity);
  const link = f(card, "link");
  link.dataset.link = m.link || "unknown";
  setText(link, `link ${m.link || "unknown"}${stale ? " (last known)" : ""} · last packet ${fmtAge(age)} ago`);
  const sch = m.schedule;
  setText(f(card, "schedule"), sch ? `${sch.name} v${sch.version} (${sch.state})` : "");

  const s = m.setting;
  const wl = f(card, "wavelength");
  setText(wl, s ? `${s.wavelength_nm} nm` : "– nm");
  wl.style.setProperty("--wl", s ? `var(--wl-${s.wavelength_nm})` : "var(--muted)");
  setText(f(card, "exposure"), s ? fmtExposure(s.exposure_s) : "–");
  setText(f(card, "gain"), s ? `${fmt(s.gain_db, 0)} dB` : "–");
  const depth = m.sensors?.depth_m ?? s?.depth_m;
  setText(f(card, "depth"), depth === null || depth === undefined ? "–" : fmt(depth, 0));
  setText(f(card, "phase"), m.phase || "–");

  const fr = m.shown;
  const fs = f(card, "frame-status");
  if (fr) {
    // A frame the schedule saturates by design is expected: said, not coloured as a problem.
    const expected = qualityKey(fr) === "saturated_by_design";
    fs.className = expected ? "status-expected" : `status-${fr.status}`;
    fs.title = expected ? "the schedule's preview predicts this setting saturated: expected, not a fault" : "";
    setText(fs, fr.status === "ok" ? "ok" : expected ? "saturated by design" : `${fr.status}${fr.reason ? ` (${fr.reason.replaceAll("_", " ")})` : ""}`);
    setText(f(card, "icenter"), fr.i_center_gray === null ? "–" : `${fmt(fr.i_center_gray, 1)} gray`);
  }
  // Rates name their window: between test stops a 10 s rate reads 0 long before the minute does.
  setText(f(card, "frame-age"), m.lastFrameAt === null ? "" : ` · ${fmtAge((now - m.lastFrameAt) / 1000)} ago`);
  const perMin = f(card, "frames-min");
  setText(perMin, m.frames_last_min === null || m.frames_last_min === undefined ? "–" : String(m.frames_last_min));
  perMin.title = m.frames_per_s === null || m.frames_per_s === undefined ? "" : `${fmt(m.frames_per_s, 2)} frames/s over the last 10 s`;

  const a = m.attitude || {};
  setText(f(card, "tilt"), fmt(a.tilt_deg, 2));
  setText(f(card, "rotation"), fmt(a.rotation_rate_dps, 2));
  setText(f(card, "heave"), fmt(a.heave_period_s, 1));
  const sn = m.sensors || {};
  setText(f(card, "temperature"), fmt(sn.temperature_c, 1));
  setText(f(card, "humidity"), fmt(sn.humidity_pct, 1));
  setText(f(card, "sensor-age"), m.sensorsAt ? fmtAge((now - m.sensorsAt) / 1000) : "–");
}

/** The quality bar: frames by status/reason, and the latest frames as a strip of coloured ticks. */
export function updateQuality(card, quality, recent) {
  // ok first, then what the schedule saturates by design (expected), then the problems, largest first
  const order = (k) => (k === "ok" ? 0 : k === "saturated_by_design" ? 1 : 2);
  const entries = Object.entries(quality || {}).sort((a, b) => order(a[0]) - order(b[0]) || b[1] - a[1]);
  const total = entries.reduce((n, [, v]) => n + v, 0);
  const bar = f(card, "qbar");
  const legend = f(card, "qlegend");
  bar.replaceChildren(
    ...entries.map(([k, v]) => el("span", { class: qualityClass(k), style: { width: `${(100 * v) / total}%` }, title: `${qualityLabel(k)}: ${v}` })),
  );
  legend.replaceChildren(
    ...(total
      ? entries.map(([k, v]) =>
          el("span", { "data-quality": k }, el("i", { class: qualityClass(k) }), `${qualityLabel(k, { bare: !quality.saturated_by_design })} ${v} (${Math.round((100 * v) / total)} %)`),
        )
      : [el("span", { class: "muted" }, "no analysed frames yet")]),
  );
  f(card, "recent").replaceChildren(...recent.map((k) => el("span", { class: qualityClass(k), title: qualityLabel(k) })));
}
