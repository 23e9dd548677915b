// Review: the audit log, readably. Who did what: operators' commands to the modules and the modules'
// answers (matched by the command's short id), alarm acknowledgements, calibration changes and
// re-analyses; each entry's full record one click away, the whole log as CSV.

import { api, query } from "./api.js";
import { utc } from "./format.js";
import { $, el, lrm } from "./ui.js";

const KINDS = {
  "": "everything",
  command: "commands sent",
  answer: "modules' answers",
  alarm: "alarm acknowledgements",
  calibration: "calibration changes",
  reanalysis: "re-analyses",
};
const ANSWERS = new Set(["command.accepted", "command.in_progress", "command.done", "command.rejected"]);
let kind = "";

function kindOf(a) {
  if (ANSWERS.has(a.action)) return "answer";
  return a.action.split(".")[0];
}

const shortId = (id) => (id ? `#${String(id).slice(0, 8)}` : "");
const moduleOf = (target) => (String(target || "").startsWith("module:") ? `${lrm(target.slice(7))}` : target);

function scheduleText(s) {
  if (!s) return "a schedule";
  const grid = `${s.exposures_s.length} exposure${s.exposures_s.length === 1 ? "" : "s"} × ${s.gains_db.length} gain${s.gains_db.length === 1 ? "" : "s"} × ${s.repeats}`;
  const blocks = s.blocks?.length ? ` + ${s.blocks.length} block${s.blocks.length === 1 ? "" : "s"}` : "";
  return `${s.name} v${s.version} (${grid}${blocks} at ${s.wavelengths_nm.join("/")} nm)`;
}

/** One sentence for an audit entry. */
export function describe(a) {
  const d = a.details || {};
  if (ANSWERS.has(a.action)) {
    const what = `${d.action === "set_schedule" ? "the schedule change" : `the ${d.action} command`} ${shortId(d.command_id)}`;
    const m = moduleOf(a.target);
    if (a.action === "command.accepted") return `${m} accepted ${what}`;
    if (a.action === "command.in_progress") return `${m} accepted ${what} and applies it at the end of the current setting`;
    if (a.action === "command.done") return `${m} applied ${what}`;
    return `${m} rejected ${what}: ${d.reason || "no reason given"}`;
  }
  if (a.action === "command.set_schedule") {
    const when = d.apply === "end_of_setting" ? "at the end of the current setting" : "now";
    return `sent ${scheduleText(d.schedule)} to ${moduleOf(a.target)}, to apply ${when} ${shortId(d.command_id)}`;
  }
  if (a.action.startsWith("command.")) {
    return `asked ${moduleOf(a.target)} to ${a.action.slice(8)} ${shortId(d.command_id)}`;
  }
  if (a.action === "alarm.ack") {
    return `acknowledged the ${String(d.kind || "").replaceAll("_", " ")} alarm ${d.key ? `(${d.key})` : a.target}`;
  }
  if (a.action === "calibration.add") {
    return `stored calibration ${String(a.target).replace(/^calibration:/, "")}${d.source ? ` from ${d.source}` : ""}`;
  }
  if (a.action === "calibration.use") return `${a.target.replace(":", " ")} now uses calibration record ${d.calibration_id} (run ${d.run_id})`;
  if (a.action === "reanalysis.start") {
    return `started re-analysis run ${d.run_id} of ${a.target.replace(":", " ")}${d.calibration_id ? ` with calibration record ${d.calibration_id}` : ""}`;
  }
  return a.target;
}

function row(a) {
  const fromModule = String(a.actor).startsWith("module:");
  return el(
    "tr",
    { "data-audit-id": a.id, "data-kind": kindOf(a) },
    el("td", {}, utc(a.t_unix_s)),
    el("td", { class: fromModule ? "actor-module" : "" }, fromModule ? `${moduleOf(a.actor)} (module)` : a.actor),
    el("td", {}, el("code", {}, a.action)),
    el("td", { class: "what" }, describe(a)),
    el(
      "td",
      {},
      a.details && Object.keys(a.details).length
        ? el("details", {}, el("summary", {}, "record"), el("pre", {}, JSON.stringify(a.details, null, 2)))
        : "",
    ),
  );
}

export async function showAudit() {
  const t = $("#audit-table");
  const tools = $("#audit-tools");
  if (!tools.childElementCount) {
    tools.append(
      el(
        "label",
        {},
        "show ",
        el(
          "select",
          {
            id: "audit-kind",
            onchange: (ev) => {
              kind = ev.target.value;
              showAudit();
            },
          },
          ...Object.entries(KINDS).map(([k, label]) => el("option", { value: k }, label)),
        ),
      ),
      el("button", { type: "button", id: "audit-refresh", onclick: () => showAudit() }, "Refresh"),
      el("a", { class: "button", id: "audit-export", href: "/api/audit/export", download: "audit.csv", title: "the whole audit log as CSV" }, "Export CSV"),
      el("span", { class: "muted", id: "audit-count" }),
    );
  }
  let rows;
  try {
    rows = await api(`/api/audit${query({ limit: 500 })}`);
  } catch (err) {
    t.replaceChildren(el("caption", { class: "error-msg" }, err.message));
    return;
  }
  const shown = rows.filter((a) => !kind || kindOf(a) === kind);
  $("#audit-count").textContent = `${shown.length} of the latest ${rows.length} entries, newest first`;
  t.replaceChildren(
    el("thead", {}, el("tr", {}, ...["time (UTC)", "who", "action", "what happened", "details"].map((h) => el("th", {}, h)))),
    el(
      "tbody",
      {},
      ...shown.map(row),
      ...(shown.length ? [] : [el("tr", {}, el("td", { colspan: 5, class: "empty" }, rows.length ? "Nothing of this kind yet." : "The audit log is empty."))]),
    ),
  );
}
