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
