// The preview of one pass of a schedule (POST /api/schedules/preview): frames, duration, and per
// module a grid of its settings (exposure x gain, one grid per wavelength) coloured by what the frames
// seen so far predict: ok, too dark, saturated, or unknown (no usable frame at that wavelength yet).

import { fmt, fmtExposure, plural } from "./format.js";
import { el, lrm } from "./ui.js";

export const VERDICTS = {
  ok: "ok",
  too_dark: "too dark",
  saturated: "saturated",
  unknown: "unknown",
};

export function fmtDuration(s) {
  if (s === null || s === undefined) return "–";
  if (s < 90) return `${Math.round(s)} s`;
  if (s < 5400) return `${Math.floor(s / 60)} min ${String(Math.round(s % 60)).padStart(2, "0")} s`;
  return `${(s / 3600).toFixed(1)} h`;
}

function legend() {
  return el(
    "div",
    { class: "verdict-legend" },
    ...Object.entries(VERDICTS).map(([k, label]) => el("span", {}, el("i", { class: `v-${k}` }), label)),
  );
}

/** One wavelength's grid: rows are exposures, columns gains; settings not in the schedule stay blank. */
function grid(module, wl, preds, exposures, gains) {
  const at = new Map(preds.map((p) => [`${p.exposure_s}|${p.gain_db}`, p]));
  return el(
    "table",
    { class: "verdict-grid", "data-module": module, "data-wl": wl, "aria-label": `module ${module} at ${wl} nm` },
    el("caption", { style: { "--wl": `var(--wl-${wl})` } }, `${wl} nm`),
    el(
      "thead",
      {},
      el("tr", {}, el("th", { class: "corner" }, "s \\ dB"), ...gains.map((g) => el("th", { scope: "col" }, String(g)))),
    ),
    el(
      "tbody",
      {},
      ...exposures.map((e) =>
        el(
          "tr",
          {},
          el("th", { scope: "row" }, fmtExposure(e)),
          ...gains.map((g) => {
            const p = at.get(`${e}|${g}`);
            if (!p) return el("td", { class: "v-none" });
            const gray = p.center_gray === null ? "?" : Math.round(p.center_gray) > 255 ? ">255" : Math.round(p.center_gray);
            const what = p.center_gray === null ? "no usable frame at this wavelength yet" : `centre gray ≈ ${fmt(p.center_gray, 0)}`;
            return el(
              "td",
              {
                class: `v-${p.verdict}`,
                "data-verdict": p.verdict,
                title: `${module} · ${wl} nm · ${fmtExposure(e)} · ${g} dB: ${what} → ${VERDICTS[p.verdict]}`,
              },
              String(gray),
            );
          }),
        ),
      ),
    ),
  );
}

function summaryLine(module, counts, n) {
  const parts = Object.keys(VERDICTS)
    .filter((k) => counts[k])
    .map((k) => el("span", { class: `count v-text-${k}` }, `${counts[k]} ${VERDICTS[k]}`));
  return el("span", { class: "summary" }, ...(parts.length || !n ? parts : [el("span", { class: "muted" }, plural(n, "setting"))]));
}

/**
 * Draw a preview into `box`.
 * @param {object} p the server's answer; `modules` the modules to show (the selected one first).
 */
export function renderPreview(box, p, { modules, selected, error }) {
  if (error) {
    box.replaceChildren(el("h3", {}, "Preview of one pass"), el("p", { class: "error-msg" }, error));
    box.dataset.state = "error";
    return;
  }
  if (!p) {
    box.replaceChildren(el("h3", {}, "Preview of one pass"), el("p", { class: "muted" }, "checking…"));
    box.dataset.state = "checking";
    return;
  }
  box.dataset.state = p.ok ? "ok" : "problems";
  const head = el(
    "div",
    { class: "preview-head" },
    el("div", { class: "stat" }, el("div", { class: "label" }, "frames per pass"), el("div", { class: "big", id: "preview-frames" }, String(p.n_frames))),
    el("div", { class: "stat" }, el("div", { class: "label" }, "one pass takes about"), el("div", { class: "big", id: "preview-duration" }, fmtDuration(p.pass_duration_s))),
    el(
      "div",
      { class: "stat", title: p.lem_dwell_s ? `the rest of a pass the camera waits for the LEM's colour (${fmtDuration(p.lem_dwell_s)} each)` : "" },
      el("div", { class: "label" }, "camera shooting"),
      el("div", { class: "big", id: "preview-busy" }, p.busy_share == null ? "–" : `${Math.round(100 * p.busy_share)} %`),
    ),
    el(
      "div",
      { class: "stat", title: limitsTitle(p.camera_limits) },
      el("div", { class: "label" }, "camera limits"),
      el("div", { class: `big ${p.ok ? "status-ok" : "status-rejected"}` }, p.ok ? "ok" : plural(p.problems.length, "problem")),
      p.camera_limits ? el("div", { class: "muted hint", id: "preview-limits" }, ...limitsLines(p.camera_limits)) : null,
    ),
    legend(),
  );
  const sections = [];
  for (const m of modules) {
    const preds = p.predictions?.[m];
    const settings = preds || [];
    const wls = [...new Set(settings.map((s) => s.wavelength_nm))];
    const exposures = [...new Set(settings.map((s) => s.exposure_s))].sort((a, b) => a - b);
    const gains = [...new Set(settings.map((s) => s.gain_db))].sort((a, b) => a - b);
    const body = preds
      ? el("div", { class: "grids" }, ...wls.map((wl) => grid(m, wl, settings.filter((s) => s.wavelength_nm === wl), exposures, gains)))
      : el("p", { class: "muted" }, `No analysed frames from ${lrm(m)} yet: every setting is unknown.`);
    sections.push(
      el(
        "div",
        { class: `preview-module${m === selected ? " selected" : ""}`, "data-module": m },
        el("h4", {}, `${lrm(m)}${m === selected ? " (selected)" : ""} `, summaryLine(m, p.summary?.[m] || { unknown: 0 }, settings.length)),
        body,
      ),
    );
  }
  const warnings = (p.warnings || []).map((w) => el("li", {}, w));
  box.replaceChildren(
    el("h3", {}, "Preview of one pass ", el("span", { class: "muted hint" }, "judged from the frames seen so far in this dive")),
    head,
    ...(warnings.length ? [el("ul", { class: "preview-warnings", id: "preview-warnings", role: "note" }, ...warnings)] : []),
    ...sections,
  );
}

/** ["exposure 10 µs – 10 s", "gain 0 – 10 dB, steps of 1 dB"]: the ranges the schedule was checked against. */
function limitsLines(c) {
  const s = (v) => (v >= 1 ? `${+v.toPrecision(3)} s` : v >= 1e-3 ? `${+(v * 1e3).toPrecision(3)} ms` : `${+(v * 1e6).toPrecision(3)} µs`);
  const step = c.gain_step_db > 0 ? `, steps of ${+c.gain_step_db.toPrecision(3)} dB` : "";
  return [
    el("div", {}, `exposure ${s(c.exposure_range_s[0])} – ${s(c.exposure_range_s[1])}`),
    el("div", {}, `gain ${c.gain_range_db[0]} – ${c.gain_range_db[1]} dB${step}`),
  ];
}

function limitsTitle(c) {
  return c ? `checked against ${c.source}` : "";
}
