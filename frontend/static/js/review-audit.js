// Review: the audit log, readably. Who did what: operators' commands to the modules and the modules'
// answers (matched by the command's short id), alarm acknowledgements, calibration changes and
// re-analyses, each in the server's words (the CSV's "what" column); each entry's full record one
// click away, the whole log as CSV.

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
const ANSWERS = new Set(["command.accepted", "command.in_progress", "command.done", "command.rejected"]); // storage/audit.py
let kind = "";

function kindOf(a) {
  if (ANSWERS.has(a.action)) return "answer";
  return a.action.split(".")[0];
}

const moduleOf = (target) => (String(target || "").startsWith("module:") ? `${lrm(target.slice(7))}` : target);

function row(a) {
  const fromModule = String(a.actor).startsWith("module:");
  return el(
    "tr",
    { "data-audit-id": a.id, "data-kind": kindOf(a) },
    el("td", {}, utc(a.t_unix_s)),
    el("td", { class: fromModule ? "actor-module" : "" }, fromModule ? `${moduleOf(a.actor)} (module)` : a.actor),
    el("td", {}, el("code", {}, a.action)),
    el("td", { class: "what" }, a.what), // said by the server (storage/audit.py), as the CSV says it
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
