// Numbers, times and colours as the dashboard shows them (times in UTC, as everywhere in camcal).

export const WAVELENGTHS = [405, 460, 525];

/** How bad a state is: MAJOR outranks INVALID (stale data), which outranks MINOR; INFO (a module that
 * signed off) is news, not a fault. */
export const SEVERITY_RANK = { OK: 0, INFO: 0, MINOR: 1, INVALID: 2, MAJOR: 3 };

/** The CSS colour of a wavelength (the theme's --wl-NNN variable). */
export function wlColor(nm) {
  const v = getComputedStyle(document.documentElement).getPropertyValue(`--wl-${nm}`).trim();
  return v || "#999";
}

export function fmt(value, digits = 1) {
  if (value === null || value === undefined || Number.isNaN(value)) return "–";
  return Number(value).toFixed(digits);
}

/**
 * A value with its error, both to the error's two significant digits: "11.153 ± 0.0083" would be
 * "11.1530 ± 0.0083", and "11.3 ± 0.0" (an error rounded away) never shows.
 */
export function fmtPm(value, err) {
  if (value === null || value === undefined) return "–";
  if (!err || !Number.isFinite(err) || err <= 0) return fmt(value, 1);
  const digits = Math.max(0, Math.min(6, 1 - Math.floor(Math.log10(err))));
  return `${fmt(value, digits)} ± ${fmt(err, digits)}`;
}

/** Exposure: 0.02 s, 0.5 s, 1 s. */
export function fmtExposure(s) {
  if (s === null || s === undefined) return "–";
  return `${Number(s) < 0.1 ? Number(s).toFixed(2) : Number(s).toPrecision(2).replace(/\.0+$/, "")} s`;
}

export function fmtAge(s) {
  if (s === null || s === undefined || !Number.isFinite(s)) return "never";
  if (s < 10) return `${s.toFixed(1)} s`;
  if (s < 120) return `${Math.round(s)} s`;
  if (s < 7200) return `${Math.round(s / 60)} min`;
  return `${(s / 3600).toFixed(1)} h`;
}

/** "2026-11-22 01:14:05" in UTC from UNIX seconds. */
export function utc(t, { ms = false, date = true } = {}) {
  if (t === null || t === undefined) return "–";
  const iso = new Date(t * 1000).toISOString();
  const clock = iso.slice(11, ms ? 23 : 19);
  return date ? `${iso.slice(0, 10)} ${clock}` : clock;
}

/** A plotly date string (plotly dates are zone-less: we give it UTC). */
export function plotDate(t) {
  return new Date(t * 1000).toISOString().slice(0, 23).replace("T", " ");
}

/** UNIX seconds from a plotly date string (UTC, see plotDate). */
export function fromPlotDate(s) {
  return Date.parse(`${String(s).replace(" ", "T")}Z`) / 1000;
}

/** Value for <input type="datetime-local"> from UNIX seconds (UTC) and back. */
export function toLocalInput(t) {
  return t === null || t === undefined ? "" : new Date(t * 1000).toISOString().slice(0, 19);
}

export function fromLocalInput(v) {
  return v ? Date.parse(`${v}Z`) / 1000 : null;
}

export const REASONS = ["saturated", "too_dark", "no_source", "off_edge", "unreadable", "bad_format", "bad_metadata"];

/**
 * The quality key of an analysed frame: "ok", the reason it was rejected, or "saturated_by_design" for a
 * saturated frame at a setting the schedule's preview predicts saturated (server/saturation.py): only
 * the unexpected ones are a problem.
 */
export function qualityKey(frame) {
  if (frame.status === "ok") return "ok";
  if (frame.reason === "saturated" && frame.by_design) return "saturated_by_design";
  return frame.reason || frame.status;
}

const QUALITY_LABELS = { saturated: "saturated, unexpected", saturated_by_design: "saturated by design" };

/** A quality key in words ("too dark", "saturated by design"). */
export function qualityLabel(key, { bare = false } = {}) {
  if (bare && key === "saturated") return "saturated";
  return QUALITY_LABELS[key] || key.replaceAll("_", " ");
}

/** Colour class of a quality key (ok or a rejection reason). */
export function qualityClass(key) {
  return ["ok", "saturated", "saturated_by_design", "too_dark", "no_source", "off_edge"].includes(key) ? `q-${key}` : "q-other";
}

export function plural(n, word) {
  return `${n} ${word}${n === 1 ? "" : "s"}`;
}
