// The control page's module side: the module tabs, the selected module's schedule and link, its newest
// frames (with the schedule version they were taken under), and which buttons an operator may press.

import { fmt, fmtExposure, utc } from "./format.js";
import { $, el, lrm, setText } from "./ui.js";

const LINK_DOT = { up: "●", down: "○", unknown: "◌" };

export function renderTabs(tabs, modules, selected, onSelect) {
  const ids = [...modules.keys()].sort();
  const key = JSON.stringify(ids.map((id) => [id, modules.get(id).link, modules.get(id).schedule, id === selected]));
  if (tabs.dataset.key === key) return;
  tabs.dataset.key = key;
  tabs.replaceChildren(
    ...ids.map((id) => {
      const m = modules.get(id);
      return el(
        "button",
        { type: "button", role: "tab", "aria-selected": String(id === selected), "data-module": id, onclick: () => onSelect(id) },
        el("span", { class: `dot link-${m.link}`, title: `link ${m.link}` }, LINK_DOT[m.link] || "◌"),
        `${lrm(id)}`,
        el("small", {}, m.schedule ? ` ${m.schedule.name} v${m.schedule.version}` : ""),
      );
    }),
  );
}

export function renderStatus(box, list, m, mismatch = null) {
  if (!m) {
    box.replaceChildren(el("p", { class: "empty" }, "Waiting for the modules to report…"));
    return;
  }
  setText($("#module-title"), `${lrm(m.id)}${m.distance_m ? ` · ${fmt(m.distance_m, 2)} m from the LEM` : ""}`);
  const s = m.schedule;
  const up = m.link === "up";
  box.replaceChildren(
    el(
      "div",
      { class: "module-schedule" },
      el("span", { class: "big", id: "current-schedule" }, s ? `${s.name} v${s.version}` : "–"),
      el(
        "span",
        { class: `run-state state-${s?.state || "unknown"}${up ? "" : " last-known"}`, id: "run-state" },
        `${s?.state || "unknown"}${s && !up ? " (last known)" : ""}`,
      ),
    ),
    el(
      "p",
      { class: "link-state", "data-link": m.link, id: "module-link" },
      `link ${m.link}`,
      up ? "" : " — commands wait (pending) until the module reconnects",
    ),
    m.deferred_shots
      ? el(
          "p",
          { class: "muted", id: "deferred-shots" },
          `${m.deferred_shots} shot${m.deferred_shots === 1 ? "" : "s"} since its start taken at a later turn of their colour: `,
          "a wavelength's run of shots is longer than the LEM shows a colour (the schedule's preview says by how much), ",
          "so each λ_att visit holds part of the settings",
        )
      : "",
    mismatch ? el("p", { class: "warn-note", id: "schedule-mismatch", role: "status" }, `⚠ ${mismatch}`) : "",
  );
  list.replaceChildren(
    ...(m.recent.length
      ? m.recent.map((f) =>
          el(
            "li",
            { class: f.schedule_version === s?.version ? "current" : "older", "data-version": f.schedule_version ?? "" },
            el("span", { class: "muted" }, utc(f.captured_unix_s, { date: false })),
            el("span", { class: "wl-chip", style: { "--wl": `var(--wl-${f.wavelength_nm})` } }, `${f.wavelength_nm} nm`),
            el("span", {}, fmtExposure(f.exposure_s)),
            el("span", {}, `${f.gain_db} dB`),
            el("span", { class: "ver" }, f.schedule_version ? `v${f.schedule_version}` : ""),
          ),
        )
      : [el("li", { class: "empty" }, "no frame yet")]),
  );
}

/** Which actions the module's state allows (any, while it has not reported one). */
function allowedActions(st) {
  return {
    start: !st || st === "stopped" || st === "idle",
    pause: !st || st === "running",
    resume: !st || st === "paused",
    stop: !st || st === "running" || st === "paused",
  };
}

/** Read-only pages say what the login is for; an operator gets the buttons the module's state allows. */
export function renderPermissions(m, op, sent = null) {
  $("#readonly-note").hidden = Boolean(op);
  const send = $("#send-schedule");
  if (send) {
    send.disabled = !op || !m || Boolean(sent);
    send.title = !op
      ? "log in as operator to send a schedule"
      : sent
        ? `sent as command #${sent.command.slice(0, 8)}: change the schedule (or when to apply it) to send again`
        : "check the schedule, then confirm before it is sent";
    setText(send, !m ? "Send…" : sent ? `Sent to ${lrm(m.id)} ✓` : `Send to ${lrm(m.id)}…`);
  }
  const st = m?.schedule?.state;
  const allowed = allowedActions(st);
  for (const b of document.querySelectorAll("#actions [data-action]")) {
    const a = b.dataset.action;
    b.disabled = !op || !m || !allowed[a];
    b.title = !op ? "log in as operator to control the module" : !allowed[a] ? `${lrm(m?.id)} is ${st}` : b.dataset.title;
  }
}
