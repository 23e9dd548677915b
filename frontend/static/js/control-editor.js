// The schedule editor: a form for the compact schedule (exposures x gains x repeats x wavelengths,
// extra blocks, order, pause) and where the server's validation messages appear, at their field.
//
// The form checks nothing itself beyond splitting lists: the server (POST /api/schedules/preview and
// the send) is the one judge, so the page can never disagree with what the module will be sent.

import { WAVELENGTHS } from "./format.js";
import { $, el } from "./ui.js";

/** "0.02, 0.05 0.1" -> [0.02, 0.05, 0.1]; a token that is not a number is sent as typed (the server names it). */
function parseList(text) {
  return String(text)
    .split(/[\s,;]+/)
    .filter(Boolean)
    .map((t) => (t.trim() !== "" && Number.isFinite(Number(t)) ? Number(t) : t));
}

const listText = (values) => (values || []).join(", ");

function numberOrRaw(v) {
  return v.trim() !== "" && Number.isFinite(Number(v)) ? Number(v) : v;
}

function errorSlot(path) {
  return el("div", { class: "field-error", "data-error-for": path, role: "alert" });
}

function textField(path, label, hint, attrs = {}) {
  const id = `f-${path.replaceAll(".", "-")}`;
  return el(
    "div",
    { class: "field-row", "data-field": path },
    el("label", { for: id }, label, hint ? el("span", { class: "hint" }, hint) : null),
    el("input", { type: "text", id, name: path, spellcheck: "false", ...attrs }),
    errorSlot(path),
  );
}

export class ScheduleEditor {
  /**
   * @param {HTMLFormElement} form
   * @param {object} hooks onChange() after any edit
   */
  constructor(form, { onChange }) {
    this.form = form;
    this.onChange = onChange;
    this.blocks = [];
    this.build();
  }

  build() {
    const f = this.form;
    const wl = el(
      "div",
      { class: "field-row", "data-field": "wavelengths_nm" },
      el("span", { class: "label" }, "wavelengths", el("span", { class: "hint" }, "the LEM's colours to photograph")),
      el(
        "div",
        { class: "checks" },
        ...WAVELENGTHS.map((nm) =>
          el(
            "label",
            { class: "wl-check", style: { "--wl": `var(--wl-${nm})` } },
            el("input", { type: "checkbox", name: "wavelengths_nm", value: String(nm) }),
            `${nm} nm`,
          ),
        ),
      ),
      errorSlot("wavelengths_nm"),
    );
    const order = el(
      "div",
      { class: "field-row", "data-field": "order" },
      el("label", { for: "f-order" }, "order", el("span", { class: "hint" }, "the outer loop of a pass")),
      el(
        "select",
        { id: "f-order", name: "order", onchange: () => this.orderHint() },
        el("option", { value: "wavelength" }, "by wavelength"),
        el("option", { value: "setting" }, "by setting"),
      ),
      el("div", { class: "hint order-hint", id: "order-hint" }),
      errorSlot("order"),
    );
    this.blocksBox = el("div", { class: "blocks", id: "blocks" });
    f.replaceChildren(
      el("div", { class: "start-from" }, el("label", { for: "start-from" }, "Start from"), el("select", { id: "start-from", name: "start_from" })),
      el("p", { class: "muted start-note", id: "start-note" }),
      el(
        "div",
        { class: "schedule-fields" },
        textField("name", "name", "what the module and the frames will say"),
        textField("repeats", "repeats", "frames per setting", { inputmode: "numeric" }),
        textField("exposures_s", "exposures", "seconds, comma-separated", { inputmode: "decimal" }),
        textField("gains_db", "gains", "dB, comma-separated", { inputmode: "decimal" }),
        wl,
        order,
        textField("pause_s", "pause", "seconds idle after each pass", { inputmode: "decimal" }),
      ),
      el(
        "fieldset",
        { class: "blocks-set" },
        el("legend", {}, "Blocks ", el("span", { class: "hint" }, "further grids taken after the main one (e.g. a linearity scan's gain sweep)")),
        this.blocksBox,
        el("button", { type: "button", id: "add-block", onclick: () => this.addBlock({ exposures_s: [], gains_db: [], repeats: 1 }, true) }, "+ Add a block"),
      ),
      el("div", { class: "form-error", "data-error-for": "schedule", role: "alert" }),
      el(
        "div",
        { class: "send-row" },
        el(
          "fieldset",
          { class: "apply", "data-field": "apply" },
          el("legend", {}, "Apply"),
          el("label", {}, el("input", { type: "radio", name: "apply", value: "end_of_setting", checked: true }), "at the end of the current setting"),
          el("label", {}, el("input", { type: "radio", name: "apply", value: "now" }), "now (cuts the current setting short)"),
        ),
        el("span", { class: "spacer" }),
        el(
          "div",
          { class: "send-box" },
          el("button", { type: "submit", class: "primary", id: "send-schedule" }, "Send…"),
          el("span", { class: "muted", id: "send-note", role: "status" }),
        ),
      ),
    );
    f.addEventListener("input", (ev) => {
      if (ev.target.name !== "start_from" && ev.target.name !== "apply") this.changed();
    });
  }

  orderHint() {
    const hint = $("#order-hint", this.form);
    if (hint) {
      hint.textContent =
        this.input("order").value === "setting"
          ? "each setting at every wavelength in turn (the LEM changes colour often)"
          : "every setting at the first wavelength, then the next (the LEM changes colour least)";
    }
  }

  changed() {
    this.onChange?.();
  }

  addBlock(block, focus = false) {
    const i = this.blocks.length;
    const box = el(
      "div",
      { class: "block", "data-block": i },
      el("div", { class: "block-head" }, el("strong", {}, `Block ${i + 1}`), el("button", { type: "button", class: "remove-block", title: `remove block ${i + 1}`, onclick: () => this.removeBlock(i) }, "Remove")),
      textField(`blocks.${i}.exposures_s`, "exposures", "s"),
      textField(`blocks.${i}.gains_db`, "gains", "dB"),
      textField(`blocks.${i}.repeats`, "repeats"),
    );
    this.blocksBox.append(box);
    this.blocks.push(box);
    this.input(`blocks.${i}.exposures_s`).value = listText(block.exposures_s);
    this.input(`blocks.${i}.gains_db`).value = listText(block.gains_db);
    this.input(`blocks.${i}.repeats`).value = String(block.repeats ?? 1);
    if (focus) {
      this.input(`blocks.${i}.exposures_s`).focus();
      this.changed();
    }
  }

  removeBlock(i) {
    const spec = this.read();
    spec.blocks.splice(i, 1);
    this.fill(spec);
    this.changed();
  }

  input(path) {
    return this.form.querySelector(`[name="${path}"]`);
  }

  /** Put a schedule in the form. */
  fill(spec) {
    this.input("name").value = spec.name ?? "custom";
    this.input("exposures_s").value = listText(spec.exposures_s);
    this.input("gains_db").value = listText(spec.gains_db);
    this.input("repeats").value = String(spec.repeats ?? 1);
    this.input("pause_s").value = String(spec.pause_s ?? 0);
    this.input("order").value = spec.order || "wavelength";
    this.orderHint();
    const wls = new Set((spec.wavelengths_nm || WAVELENGTHS).map(Number));
    for (const box of this.form.querySelectorAll('[name="wavelengths_nm"]')) box.checked = wls.has(Number(box.value));
    this.blocksBox.replaceChildren();
    this.blocks = [];
    for (const b of spec.blocks || []) this.addBlock(b);
    this.showProblems([]);
  }

  /** The schedule in the form, in the API's shape (without a version: the page sets it). */
  read() {
    const v = (path) => this.input(path).value;
    return {
      name: v("name").trim(),
      exposures_s: parseList(v("exposures_s")),
      gains_db: parseList(v("gains_db")),
      repeats: numberOrRaw(v("repeats")),
      wavelengths_nm: [...this.form.querySelectorAll('[name="wavelengths_nm"]:checked')].map((b) => Number(b.value)),
      blocks: this.blocks.map((_, i) => ({
        exposures_s: parseList(v(`blocks.${i}.exposures_s`)),
        gains_db: parseList(v(`blocks.${i}.gains_db`)),
        repeats: numberOrRaw(v(`blocks.${i}.repeats`)),
      })),
      order: v("order"),
      pause_s: numberOrRaw(v("pause_s")),
    };
  }

  apply() {
    return this.form.querySelector('[name="apply"]:checked')?.value || "end_of_setting";
  }

  /**
   * Show the server's problems ([{field, reason}]) at their fields: "schedule.blocks.0.gains_db.2" goes to
   * the block's gains, "schedule" (the whole schedule, e.g. too many frames) under the form.
   * Returns how many were placed.
   */
  showProblems(problems) {
    for (const slot of this.form.querySelectorAll("[data-error-for]")) slot.replaceChildren();
    for (const row of this.form.querySelectorAll(".invalid")) row.classList.remove("invalid");
    for (const p of problems || []) {
      const parts = String(p.field || "").replace(/^body\./, "").split(".");
      if (parts[0] === "schedule") parts.shift();
      let slot = null;
      let row = null;
      for (let n = parts.length; n > 0 && !slot; n--) {
        const path = parts.slice(0, n).join(".");
        slot = this.form.querySelector(`[data-error-for="${path}"]`);
        row = this.form.querySelector(`[data-field="${path}"]`);
      }
      slot ||= $('[data-error-for="schedule"]', this.form);
      row?.classList.add("invalid");
      const where = slot.dataset.errorFor === "schedule" && p.field && p.field !== "schedule" ? `${p.field}: ` : "";
      slot.append(el("div", {}, `${where}${p.reason}`));
    }
    return (problems || []).length;
  }

  setStartOptions(groups, selected) {
    const select = $("#start-from", this.form);
    select.replaceChildren(
      ...groups.map((g) =>
        el(
          "optgroup",
          { label: g.label },
          ...g.options.map((o) => el("option", { value: o.value, disabled: o.disabled || false }, o.label)),
        ),
      ),
    );
    if (selected) select.value = selected;
  }
}
