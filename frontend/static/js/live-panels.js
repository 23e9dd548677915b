// The live view's shared panels: alarms with acknowledgement, and λ_att per LEM visit (numbers and plots).

import { WAVELENGTHS, SEVERITY_RANK as RANK, fmt, plural, utc, wlColor } from "./format.js";
import { drawVisitSeries } from "./lambda-profile.js";
import { el, lrm, toast } from "./ui.js";

/** The alarm list: active ones first (worst, then newest), then the five last cleared. */
/** The ingest's refused connections, in one line: counted, never shown as modules or alarms. */
export function renderRefused(box, refused) {
  const recent = refused?.last_minute || 0;
  box.hidden = !recent;
  if (!recent) return;
  const s = (refused.sources || [])[0] || {};
  const why = { unknown_key: "unknown key", plaintext: "no encryption", no_handshake: "broken handshake", not_curve: "not CURVE" }[s.reason] || s.reason;
  const text =
    `Refused connections: ${recent} in the last minute (${refused.total} in all); newest: ${why}` +
    (s.key ? ` ${s.key}` : "") +
    (s.address ? ` from ${s.address}` : "") +
    ". Nobody without a module's key gets in (a module's key is added with camcal keys create).";
  if (box.textContent !== text) box.textContent = text;
}

export function renderAlarms(list, alarms, { operator, onAck }) {
  const all = [...alarms.values()];
  const active = all
    .filter((a) => a.active)
    .sort((a, b) => RANK[b.severity] - RANK[a.severity] || b.raised_unix_s - a.raised_unix_s);
  const cleared = all.filter((a) => !a.active).sort((a, b) => (b.cleared_unix_s || 0) - (a.cleared_unix_s || 0));
  const key = JSON.stringify([active, cleared.slice(0, 5), Boolean(operator)]);
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  const row = (a) =>
    el(
      "li",
      { class: `alarm sev-${a.severity}${a.active ? "" : " cleared"}`, "data-alarm-id": a.id },
      el("span", { class: `pill sev-${a.severity}${a.active && a.severity === "MAJOR" && !a.acked_by ? " unacked" : ""}` }, a.severity),
      el(
        "span",
        { class: "msg" },
        `${a.module ? `${lrm(a.module)}: ` : ""}${a.message}`,
        el(
          "div",
          { class: "meta" },
          `${a.kind} · raised ${utc(a.raised_unix_s, { date: false })}` +
            (a.cleared_unix_s ? ` · cleared ${utc(a.cleared_unix_s, { date: false })}` : "") +
            (a.acked_by ? ` · acknowledged by ${a.acked_by}` : ""),
        ),
      ),
      a.acked_by || !a.active
        ? el("span")
        : el(
            "button",
            {
              type: "button",
              class: "ack",
              disabled: !operator,
              title: operator ? "acknowledge this alarm" : "log in as operator to acknowledge",
              onclick: (ev) => onAck(a, ev.currentTarget),
            },
            "Acknowledge",
          ),
    );
  const items = active.map(row);
  if (!active.length) items.push(el("li", { class: "empty", id: "no-alarms" }, "No active alarms."));
  if (cleared.length) {
    items.push(el("li", { class: "muted", style: { marginTop: "0.3rem" } }, "Recently cleared"));
    items.push(...cleared.slice(0, 5).map(row));
  }
  list.replaceChildren(...items);
}

/**
 * The point of a wavelength stored last: points are numbered as their visits begin, so this is the
 * newest visit as the ship received it, not the one of the latest time (a module's clock sets that:
 * an earlier simulated dive's clock ran ahead of this one's).
 */
export function newestPoint(pts) {
  let best = null;
  for (const p of pts) if (!best || (p.id ?? -1) >= (best.id ?? -1)) best = p;
  return best;
}

/** The latest λ_att per wavelength in large type, with its errors, frames, depth, time and state. */
export function renderLambdaNow(box, attenuation) {
  const items = [];
  for (const wl of WAVELENGTHS.map(String)) {
    const p = newestPoint(attenuation[wl] || []);
    const about = p
      ? `± ${fmt(p.stat_err_m, 2)} stat ± ${fmt(p.sys_err_m, 2)} sys · ${plural(p.n_frames ?? 0, "frame")} · ` +
        `${fmt(p.depth_m, 0)} m · ${utc(p.t_ship_unix_s ?? p.t_unix_s, { date: false })}` +
        (p.final === false ? " · provisional" : "")
      : "no point yet";
    items.push(
      el(
        "div",
        { class: `wl-value${p && p.final === false ? " provisional" : ""}`, style: { "--wl": wlColor(wl) }, "data-wl": wl },
        el("div", { class: "wl-name" }, `${wl} nm`),
        el("div", { class: "huge" }, p ? fmt(p.lambda_att_m, 1) : "–", el("span", { class: "unit" }, "m")),
        el("div", { class: "errs" }, about),
      ),
    );
  }
  const key = JSON.stringify(items.map((n) => n.textContent));
  if (box.dataset.key !== key) {
    box.dataset.key = key;
    box.replaceChildren(...items);
  }
}

/** λ_att per visit against time and the profile against depth (a zoom survives updates: uirevision). */
export function drawLambda(timeDiv, depthDiv, attenuation, smoothVisits = 0) {
  drawVisitSeries(timeDiv, depthDiv, attenuation, {
    smoothVisits,
    uirevision: "live",
    filename: "camcal-lambda-att",
    emptyText: "waiting for the first LEM visit…",
  }).catch((err) => toast(err.message));
}
