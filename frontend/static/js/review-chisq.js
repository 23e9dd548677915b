// Review: the newest χ² fit of a dive (λ_abs, λ_sca): values or one-sided limits, the λ_att check
// with its flag, the error scaling and the systematic budget. Read from /api/dives/{id}/fits/latest.

import { api, query } from "./api.js";
import { fmt, wlColor } from "./format.js";
import { el } from "./ui.js";

/** "39.20 ± 1.10 ± 0.30", "> 180 (95 % CL)" or "unconstrained" (metres), as the report writes it. */
export function lengthText(f, key) {
  const e = f[key] || { status: "measured", value_m: f[`${key}_m`], err_m: f[`${key}_err_m`], sys_err_m: f[`${key}_sys_err_m`] };
  if (e.status === "measured" && e.value_m !== null && e.value_m !== undefined) {
    let sys = e.sys_err_m === null || e.sys_err_m === undefined ? "" : ` ± ${fmt(e.sys_err_m, 2)}`;
    if (e.sys_text) sys = ` ${e.sys_text}`; // "± 0.30" or "+4.10/−0.90" (camcal.fitdoc)
    if (e.systematics === "no budget") sys = " (no budget)";
    return `${fmt(e.value_m, 2)} ± ${fmt(e.err_m, 2)}${sys}`;
  }
  if (e.status === "lower_limit" || e.status === "upper_limit") {
    return `${e.status === "lower_limit" ? ">" : "<"} ${Number(e.limit_m).toPrecision(3)} (${Math.round(100 * (e.cl || 0.95))} % CL)`;
  }
  return "unconstrained";
}

/** A budget cell: the line's text when the document has one, else its symmetric error. */
function errCell(text, value, bold) {
  const style = bold ? { fontWeight: 700 } : {};
  return el("td", { class: "r", style }, text ? text.replace(/^± /, "") : fmt(value, 3));
}

/** The λ_att check's word, and under it a calibration the fit pulled beyond 3σ (said below the table). */
function checkCell(f) {
  const cell = attCheckCell(f);
  if (f.nuisance_check_flagged) {
    cell.append(el("div", { class: "chisq-cal-flag", style: { color: "var(--major)", fontWeight: 700 } }, "calibration FLAGGED"));
  }
  return cell;
}

function attCheckCell(f) {
  const z = f.att_check_z;
  if (z === null || z === undefined) return el("td", { class: "muted" }, "–");
  const sz = `${z >= 0 ? "+" : ""}${fmt(z, 1)}σ`;
  if (f.att_check_agrees) return el("td", { style: { color: "var(--ok)" } }, `agrees (${sz})`);
  if (f.att_check_flagged) return el("td", { style: { color: "var(--major)", fontWeight: 700 } }, `FLAGGED (${sz})`);
  return el("td", { style: { color: "var(--minor)" } }, `differs (${sz})`);
}

function fitsTable(fits) {
  const head = ["λ", "λ_abs (m)", "λ_sca (m)", "λ_att fit (m)", "λ_att I_center (m)", "check", "χ²/ndof"];
  return el(
    "table",
    { id: "chisq-table" },
    el("thead", {}, el("tr", {}, ...head.map((h, i) => el("th", { class: i ? "r" : "" }, h)))),
    el(
      "tbody",
      {},
      ...fits.map((f) =>
        el(
          "tr",
          { "data-wl": f.wavelength_nm },
          el("td", { style: { color: wlColor(f.wavelength_nm), fontWeight: 700 } }, `${f.wavelength_nm} nm`),
          el("td", { class: "r", style: { fontWeight: 700 } }, lengthText(f, "lambda_abs")),
          el("td", { class: "r", style: { fontWeight: 700 } }, lengthText(f, "lambda_sca")),
          el("td", { class: "r" }, `${fmt(f.lambda_att_fit_m, 2)} ± ${fmt(f.lambda_att_fit_err_m, 2)}`),
          el("td", { class: "r" }, `${fmt(f.lambda_att_icenter_m, 2)} ± ${fmt(f.lambda_att_icenter_err_m, 2)}`),
          checkCell(f),
          el(
            "td",
            { class: "r" },
            `${fmt(f.chi2, 0)}/${f.ndof}${f.errors_scaled ? ` (errors ×${fmt(f.error_scale, 2)})` : ""}`,
          ),
        ),
      ),
    ),
  );
}

function budgetTable(f) {
  const b = f.systematics;
  const row = (cells, attrs = {}) => el("tr", attrs, ...cells);
  return el(
    "details",
    { class: "chisq-budget", "data-wl": f.wavelength_nm },
    el(
      "summary",
      {},
      f.lambda_abs?.sys_text && f.lambda_sca?.sys_text
        ? `${f.wavelength_nm} nm: systematic budget (λ_abs ${f.lambda_abs.sys_text} m, λ_sca ${f.lambda_sca.sys_text} m)`
        : `${f.wavelength_nm} nm: systematic budget (λ_abs ± ${fmt(b.lambda_abs_sys_m, 2)} m, λ_sca ± ${fmt(b.lambda_sca_sys_m, 2)} m)`,
    ),
    el(
      "div",
      { class: "table-wrap" },
      el(
      "table",
      {},
      el("thead", {}, row(["varied", "cases", "λ_abs (m)", "λ_sca (m)", "λ_att (m)", "note"].map((h, i) => el("th", { class: i > 1 && i < 5 ? "r" : "" }, h)))),
      el(
        "tbody",
        {},
        ...b.items.map((i) =>
          row([
            el("td", { class: "label" }, i.label),
            el("td", {}, i.cases_text ?? i.cases.join(", ")),
            errCell(i.errors_text?.[0], i.lambda_abs_err_m),
            errCell(i.errors_text?.[1], i.lambda_sca_err_m),
            errCell(i.errors_text?.[2], i.lambda_att_err_m),
            el("td", { class: "muted note" }, (i.profiled ? "floated in the fit: inside the fit error, not added. " : "") + (i.note || "")),
          ]),
        ),
        row(
          [
            el("td", { style: { fontWeight: 700 } }, "sum in quadrature"),
            el("td", {}, ""),
            errCell(b.sys_text?.[0], b.lambda_abs_sys_m, true),
            errCell(b.sys_text?.[1], b.lambda_sca_sys_m, true),
            errCell(b.sys_text?.[2], b.lambda_att_sys_m, true),
            el("td", { class: "muted" }, `refits took ${fmt(b.seconds, 1)} s`),
          ],
        ),
      ),
    ),
    ),
  );
}

/** Fill ``box`` with the newest χ² fit of the dive (of ``runId``'s inputs), or say how to make one. */
export async function showChisqFit(box, dive, runId) {
  let fit;
  try {
    // The list first (it answers 200, empty or not): a dive without a fit costs no 404 in the console.
    const kept = await api(`/api/dives/${dive.id}/fits`);
    if (!kept.some((f) => runId === null || runId === undefined || f.run_id === runId)) {
      box.replaceChildren(
        el("p", { class: "empty" }, `No χ² fit kept for this run yet: camcal fit --dive ${dive.name} --data DIR`),
      );
      return;
    }
    fit = await api(`/api/dives/${dive.id}/fits/latest${query({ run: runId })}`);
  } catch (err) {
    box.replaceChildren(el("p", { class: "error-msg" }, err.message));
    return;
  }
  const fits = fit.result?.fits || [];
  const parts = [
    el(
      "p",
      { class: "muted" },
      `Fit ${fit.id} of run ${fit.run_id}'s inputs. Each length: value (with a budget, the mean over its template samples) ± fit error (statistical and floated nuisances, ×√(χ²/ndof) where that exceeds 1) ± systematic (+up/−down where the budget is one-sided), or a one-sided 95 % CL limit where the data only bound it.`,
    ),
    el("div", { class: "table-wrap" }, fitsTable(fits)),
  ];
  for (const f of fits) {
    if (f.att_check_flagged && f.att_check_advice) {
      parts.push(el("p", { class: "error-msg chisq-flag", "data-wl": f.wavelength_nm, style: { whiteSpace: "normal" } }, `${f.wavelength_nm} nm flagged: ${f.att_check_advice}`));
    }
    if (f.nuisance_check_flagged && f.nuisance_check_advice) {
      parts.push(el("p", { class: "error-msg chisq-flag", "data-wl": f.wavelength_nm, style: { whiteSpace: "normal" } }, `${f.wavelength_nm} nm flagged: ${f.nuisance_check_advice}`));
    }
  }
  for (const f of fits) if (f.systematics) parts.push(budgetTable(f));
  box.replaceChildren(...parts);
}
