// Where a schedule in the editor starts from: the module's current schedule, one sent to it earlier,
// or a preset. A module reports only the name and version of what it runs, so its current schedule
// is the one the ship sent it as that version, or else (the schedule it booted with) the preset of
// that name: the page says which.

import { plural, utc } from "./format.js";
import { lrm } from "./ui.js";

const ABOUT = {
  trex: "the full T-REX schedule: 7 exposures × 10 gains × 20 frames at each wavelength",
  "trex-subsampled": "the T-REX exposures at four of its gains, 2 frames each: quick and representative",
  "quick-check": "a quick λ_att check: the three exposures that suit the three wavelengths, at one gain",
  "linearity-scan": "the in-situ linearity check: exposures at 6 dB, then a gain sweep at 0.05 s",
  monitoring: "long exposures (0.2–1 s) for bioluminescence and the deployment, one frame each, 5 s pause",
};

function current(m, commands, presets) {
  const sch = m.schedule;
  if (!sch) return null;
  const cmd = commands.find((c) => c.action === "set_schedule" && c.state === "done" && c.target_version === sch.version);
  if (cmd?.payload?.schedule) {
    return { spec: cmd.payload.schedule, note: `As sent to ${lrm(m.id)} by ${cmd.issued_by} at ${utc(cmd.issued_unix_s)} UTC.` };
  }
  if (presets[sch.name]) {
    return {
      spec: presets[sch.name],
      note: `${lrm(m.id)} reports only the name and version of the schedule it started with: this is the preset of that name.`,
    };
  }
  return null;
}

/**
 * The starting points for module `m`: `groups` for the <select> (optgroups of {value, label, disabled})
 * and `byValue`, value -> {spec, note}. Values: "current", "cmd:ID", "preset:NAME".
 */
export function scheduleSources(m, commands, presets) {
  const byValue = new Map();
  const sch = m.schedule;
  const cur = current(m, commands, presets);
  if (cur) byValue.set("current", cur);
  const groups = [
    {
      label: `${lrm(m.id)} now`,
      options: [
        {
          value: "current",
          label: sch ? `current: ${sch.name} v${sch.version} (${sch.state})` : "current: not reported yet",
          disabled: !cur,
        },
      ],
    },
  ];
  const sent = commands.filter((c) => c.action === "set_schedule" && c.payload?.schedule && c.target_version !== sch?.version);
  if (sent.length) {
    groups.push({
      label: "sent earlier",
      options: sent.map((c) => {
        byValue.set(`cmd:${c.id}`, {
          spec: c.payload.schedule,
          note: `As sent to ${lrm(m.id)} by ${c.issued_by} at ${utc(c.issued_unix_s)} UTC (${c.state}).`,
        });
        return {
          value: `cmd:${c.id}`,
          label: `${c.payload.schedule.name} v${c.target_version} (${c.state}, ${utc(c.issued_unix_s, { date: false })})`,
        };
      }),
    });
  }
  groups.push({
    label: "presets",
    options: Object.entries(presets).map(([name, p]) => {
      byValue.set(`preset:${name}`, { spec: p, note: ABOUT[name] ? `Preset ${name}: ${ABOUT[name]}.` : `Preset ${name}.` });
      return { value: `preset:${name}`, label: `${name} (${plural(p.n_frames, "frame")} a pass)` };
    }),
  });
  return { groups, byValue };
}

/** The settings (wavelength, exposure, gain) a schedule takes frames at, as "460|0.05|6" strings. */
function settingsOf(spec) {
  const grids = [[spec.exposures_s, spec.gains_db], ...(spec.blocks || []).map((b) => [b.exposures_s, b.gains_db])];
  const out = new Set();
  for (const [exposures, gains] of grids) {
    for (const wl of spec.wavelengths_nm) for (const e of exposures) for (const g of gains) out.add(`${wl}|${Number(e)}|${Number(g)}`);
  }
  return out;
}

/**
 * Whether the modules run schedules that λ_att cannot pair: λ_att divides a near and a far frame of
 * equal wavelength, exposure and gain, so every setting one module takes and the other does not is
 * lost to it. `specs`: [{id, schedule (as reported), spec (null if unknown)}]. Returns a sentence, or
 * null when they match (or too little is known to tell).
 */
export function mismatchText(specs) {
  const known = specs.filter((s) => s.schedule);
  if (known.length < 2) return null;
  const names = known.map((s) => `${lrm(s.id)} runs ${s.schedule.name} v${s.schedule.version}`).join(", ");
  if (known.every((s) => s.spec)) {
    const sets = known.map((s) => settingsOf(s.spec));
    const shared = [...sets[0]].filter((k) => sets.every((set) => set.has(k))).length;
    if (sets.every((set) => set.size === shared)) return null;
    const counts = known.map((s, i) => `${lrm(s.id)} ${sets[i].size}`).join(", ");
    return shared
      ? `${names}: λ_att pairs frames of equal settings, so only the ${shared} settings both take give λ_att (settings: ${counts}).`
      : `${names}: no setting in common, so no λ_att until they run matching schedules.`;
  }
  const same = known.every((s) => s.schedule.name === known[0].schedule.name && s.schedule.version === known[0].schedule.version);
  return same ? null : `${names}: λ_att needs frames of equal settings from both; their settings are not known here — check that they match.`;
}

/** The schedule module `m` runs, as a spec, where the ship can tell (else null). */
export function currentSpec(m, commands, presets) {
  return current(m, commands, presets)?.spec ?? null;
}
