// Small DOM helpers shared by both pages: elements, messages, the theme and the operator login.

import { login, logout, operator } from "./api.js";

/** el("div", {class: "x", onclick: f}, "text", child): an element (text children are escaped). */
export function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (v === null || v === undefined || v === false) continue;
    if (k.startsWith("on") && typeof v === "function") node.addEventListener(k.slice(2), v);
    else if (k === "class") node.className = v;
    else if (k === "dataset") Object.assign(node.dataset, v);
    else if (k === "style" && typeof v === "object") {
      // Custom properties ("--wl") only take through setProperty, not as plain style fields.
      for (const [name, value] of Object.entries(v)) {
        if (name.startsWith("--")) node.style.setProperty(name, value);
        else node.style[name] = value;
      }
    }
    else node.setAttribute(k, v === true ? "" : v);
  }
  for (const c of children.flat()) {
    if (c === null || c === undefined || c === false) continue;
    node.append(c instanceof Node ? c : document.createTextNode(String(c)));
  }
  return node;
}

export const $ = (sel, root = document) => root.querySelector(sel);

/** A module's name as the crew says it: "LRM-A" for id "A"; an id that already names itself ("LRM-far") as it is. */
export function lrm(id) {
  const s = String(id ?? "");
  return /^lrm/i.test(s) ? s : `LRM-${s}`;
}

/**
 * Say in the top bar that the modules are `camcal up`'s simulated ones (speed: the simulation's, or
 * null for real modules): their frames' and sensors' times run on the simulation's clock, ahead of
 * the ship's, which alarms, commands and the audit log keep.
 */
export function showSimulation(speed) {
  const chip = document.getElementById("sim-note");
  if (!chip) return;
  chip.hidden = !speed;
  if (!speed) return;
  setText(chip, `simulated dive ${speed}×`);
  chip.title =
    `The modules are simulated, their dive running ${speed} times faster than the clock. Their clock is ` +
    "mapped onto the ship's at the handshake and at every heartbeat: frames, sensors, λ_att, alarms and " +
    "commands are all drawn on the ship's clock, in the order they happened.";
}

/**
 * A dive's state beside its name: a chip "open" or "ended" (its reason as the tooltip), and where a
 * notice element is given, the ended dive's reason in words (null or an open dive: the notice hides).
 */
export function showDiveState(chip, dive, notice = null, hint = "") {
  if (!chip) return;
  const state = dive?.state ?? null;
  chip.hidden = !state;
  chip.dataset.state = state ?? "";
  if (!state) return;
  setText(chip, state === "ended" ? "dive ended" : "dive open");
  chip.title = `${state}: ${dive.state_reason || ""}`;
  if (!notice) return;
  notice.hidden = state !== "ended";
  if (state === "ended") {
    const at = dive.state_ended_unix_s ? new Date(dive.state_ended_unix_s * 1000).toISOString().slice(0, 16).replace("T", " ") : "";
    setText(
      notice,
      // (a reason read from the modules names its time already; an operator's end does not)
      `Dive ${dive.name} has ended${at && !/UTC/.test(dive.state_reason) ? ` (${at} UTC)` : ""}: ` +
        `${dive.state_reason}.${hint ? ` ${hint}` : ""}`,
    );
  }
}

/** Set text only when it changed (cheap to call on every render). */
export function setText(node, text) {
  const s = String(text);
  if (node && node.textContent !== s) node.textContent = s;
}

let toastTimer = null;

/** A message at the bottom of the page; errors stay longer. */
export function toast(message, { kind = "error", ms } = {}) {
  let box = $("#toast");
  if (!box) {
    box = el("div", { id: "toast", class: "toast", role: "status", "aria-live": "polite" });
    document.body.append(box);
  }
  box.className = `toast ${kind === "error" ? "" : "info"}`;
  box.textContent = message;
  box.hidden = false;
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => (box.hidden = true), ms ?? (kind === "error" ? 8000 : 3500));
}

// ------------------------------------------------------------------ theme
const THEME_KEY = "camcal.theme";

export function initTheme(button) {
  const apply = (t) => {
    document.documentElement.dataset.theme = t;
    if (button) {
      button.textContent = t === "night" ? "☀ Day" : "☾ Night";
      button.title = t === "night" ? "switch to the day theme (daylight)" : "switch to the night theme (dark deck)";
    }
  };
  apply(localStorage.getItem(THEME_KEY) || "night");
  button?.addEventListener("click", () => {
    const t = document.documentElement.dataset.theme === "night" ? "day" : "night";
    localStorage.setItem(THEME_KEY, t);
    apply(t);
    window.dispatchEvent(new CustomEvent("camcal:theme"));
  });
}

// ------------------------------------------------------------------ operator login
/** The "Operator login" control in the top bar; pages listen to "camcal:auth" to enable actions. */
export function mountOperator(container) {
  const dialog = el(
    "dialog",
    { id: "login-dialog", "aria-labelledby": "login-title" },
    el(
      "form",
      { method: "dialog" },
      el("h2", { id: "login-title", style: { margin: 0 } }, "Operator login"),
      el(
        "p",
        { class: "muted", style: { margin: 0 } },
        "Watching needs no token. Acknowledging alarms and re-analyses need the operator token " +
          "printed by `camcal up` (kept in this tab only).",
      ),
      el("input", {
        type: "password",
        name: "token",
        id: "login-token",
        autocomplete: "current-password",
        placeholder: "operator token",
        required: true,
        "aria-label": "operator token",
      }),
      el("p", { class: "error-msg", id: "login-error", role: "alert" }),
      el(
        "div",
        { style: { display: "flex", gap: "0.5rem", justifyContent: "flex-end" } },
        el("button", { type: "button", value: "cancel", onclick: () => dialog.close() }, "Cancel"),
        el("button", { type: "submit", class: "primary", id: "login-submit" }, "Log in"),
      ),
    ),
  );
  document.body.append(dialog);
  const form = dialog.querySelector("form");
  form.addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const token = form.token.value.trim();
    const errBox = $("#login-error", dialog);
    errBox.textContent = "";
    try {
      const name = await login(token);
      form.reset();
      dialog.close();
      toast(`logged in as ${name}`, { kind: "info" });
    } catch (err) {
      errBox.textContent = err.message;
    }
  });

  const render = () => {
    container.replaceChildren();
    const op = operator();
    if (op) {
      container.append(
        el("span", { class: "muted", id: "operator-name" }, `operator: ${op.name}`),
        el("button", { type: "button", id: "logout", onclick: () => logout() }, "Log out"),
      );
    } else {
      container.append(
        el("span", { class: "muted hide-narrow", id: "operator-name" }, "read-only"),
        el(
          "button",
          {
            type: "button",
            id: "login",
            title: "log in as operator (acknowledge alarms, start re-analyses)",
            onclick: () => {
              dialog.showModal();
              $("#login-token", dialog).focus();
            },
          },
          "Operator",
        ),
      );
    }
  };
  window.addEventListener("camcal:auth", render);
  window.addEventListener("camcal:auth-failed", (ev) => {
    // The token no longer works (e.g. the server restarted with new tokens): back to read-only.
    logout();
    toast(`${ev.detail.message} — log in again`);
  });
  render();
}

// ------------------------------------------------------------------ confirmation
/**
 * Ask before something disruptive. Resolves true only when the person presses the confirm button;
 * Escape or Cancel resolve false. `message` says what will happen, in full.
 */
export function confirmDialog({ title, message, details = [], okLabel = "Confirm", danger = false }) {
  return new Promise((resolve) => {
    const dialog = el(
      "dialog",
      { class: "confirm", id: "confirm-dialog", "aria-labelledby": "confirm-title", "aria-describedby": "confirm-message" },
      el(
        "form",
        { method: "dialog" },
        el("h2", { id: "confirm-title", style: { margin: 0 } }, title),
        el("p", { id: "confirm-message", class: "confirm-message" }, message),
        details.length ? el("ul", { class: "confirm-details" }, ...details.map((d) => el("li", {}, d))) : null,
        el(
          "div",
          { class: "dialog-buttons" },
          el("button", { type: "submit", value: "cancel", id: "confirm-cancel" }, "Cancel"),
          el("button", { type: "submit", value: "ok", id: "confirm-ok", class: danger ? "primary danger" : "primary" }, okLabel),
        ),
      ),
    );
    document.body.append(dialog);
    dialog.addEventListener("close", () => {
      resolve(dialog.returnValue === "ok");
      dialog.remove();
    });
    dialog.showModal();
    $("#confirm-cancel", dialog).focus();
  });
}
