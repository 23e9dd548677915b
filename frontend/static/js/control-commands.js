// Commands to a module: what each says, the tracker of the command being followed (pending, sent,
// accepted, in progress, done or rejected with the module's reason) and the module's command list.

import { utc } from "./format.js";
import { el, lrm } from "./ui.js";

export const FINAL = new Set(["done", "rejected"]);
const STEPS = ["pending", "sent", "accepted", "in_progress", "done"];
const STATE_LABEL = {
  pending: "pending",
  sent: "sent",
  accepted: "accepted",
  in_progress: "in progress",
  done: "done",
  rejected: "rejected",
};

/** "linearity-scan v2" for a schedule command, the action otherwise. */
export function commandWhat(c) {
  if (c.action === "set_schedule") {
    const s = c.payload?.schedule;
    return `schedule ${s?.name ?? "?"} v${c.target_version}`;
  }
  return c.action;
}

export function applyText(apply) {
  return apply === "end_of_setting" ? "at the end of the current setting" : "now";
}

function stateText(c, module) {
  const m = `${lrm(c.module)}`;
  switch (c.state) {
    case "pending":
      return module && module.link !== "up"
        ? `Pending: ${m} is offline (link ${module.link || "unknown"}). The ship keeps the command and delivers it as soon as ${m} reconnects.`
        : `Pending: the ship sends it to ${m} within a few seconds.`;
    case "sent":
      return `Sent to ${m}; waiting for its answer.`;
    case "accepted":
      return c.action === "set_schedule" && c.apply === "end_of_setting"
        ? `${m} accepted it and switches at the end of the current setting.`
        : `${m} accepted it.`;
    case "in_progress":
      return `In progress: ${m} accepted it and switches at the end of the current setting.`;
    case "done":
      if (c.action === "set_schedule") return `Done: ${m} runs ${c.payload?.schedule?.name ?? "the schedule"} v${c.target_version}.`;
      return `Done: ${m} ${{ start: "started", pause: "paused", resume: "resumed", stop: "stopped" }[c.action] || c.action}.`;
    case "rejected":
      return `Rejected by ${m}: ${c.reason || "no reason given"}.`;
    default:
      return c.state;
  }
}

/** The tracker of one command: its steps lit as the module answers, and a sentence saying where it is. */
export function renderTracker(box, c, module) {
  if (!c) {
    box.replaceChildren(el("p", { class: "muted" }, "No command sent from this page yet."));
    box.dataset.state = "";
    return;
  }
  const steps = STEPS.filter(
    (s) =>
      (s !== "in_progress" || (c.action === "set_schedule" && c.apply === "end_of_setting")) &&
      (s !== "done" || c.state !== "rejected"),
  );
  const reached = c.state === "rejected" ? -1 : steps.indexOf(c.state);
  const offline = c.state === "pending" && module && module.link !== "up";
  box.dataset.state = c.state;
  box.dataset.commandId = c.id;
  box.replaceChildren(
    el(
      "div",
      { class: "tracker-head" },
      el("strong", {}, `${commandWhat(c)} → ${lrm(c.module)}`),
      el("span", { class: "muted" }, ` · issued by ${c.issued_by} at ${utc(c.issued_unix_s, { date: false })} UTC · #${c.id.slice(0, 8)}`),
    ),
    el(
      "ol",
      { class: "steps", "aria-label": "command progress" },
      ...steps.map((s, i) =>
        el(
          "li",
          { class: i < reached ? "past" : i === reached ? (s === "done" ? "past now" : "now") : "", "data-step": s },
          STATE_LABEL[s],
        ),
      ),
      c.state === "rejected" ? el("li", { class: "now rejected", "data-step": "rejected" }, "rejected") : null,
    ),
    el("p", { class: `tracker-text state-${c.state}${offline ? " offline" : ""}`, id: "tracker-text" }, stateText(c, module)),
  );
}

/** The module's commands, newest first. */
export function renderCommands(table, commands, followed) {
  table.replaceChildren(
    el("thead", {}, el("tr", {}, ...["issued (UTC)", "command", "by", "state"].map((h) => el("th", {}, h)))),
    el(
      "tbody",
      {},
      ...commands.flatMap((c) => {
        const selected = c.id === followed ? "selected" : "";
        const row = el(
          "tr",
          { "data-command-id": c.id, class: `${selected}${c.reason ? " has-reason" : ""}` },
          el("td", {}, utc(c.issued_unix_s, { date: false })),
          el(
            "td",
            { class: "wrap" },
            commandWhat(c),
            c.action === "set_schedule" ? el("div", { class: "muted small" }, applyText(c.apply)) : null,
          ),
          el("td", { class: "wrap" }, c.issued_by),
          el("td", {}, el("span", { class: `cmd-state state-${c.state}` }, STATE_LABEL[c.state] || c.state)),
        );
        // The module's reason on a row of its own, the table's full width: a narrow column would
        // cut it or stack it a word a line.
        const reason = c.reason
          ? el("tr", { class: `reason-row ${selected}`, "data-reason-for": c.id }, el("td", { colspan: 4, class: "reason" }, c.reason))
          : null;
        return reason ? [row, reason] : [row];
      }),
      ...(commands.length ? [] : [el("tr", {}, el("td", { colspan: 4, class: "empty" }, "No commands to this module yet."))]),
    ),
  );
}
