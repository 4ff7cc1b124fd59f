//! The session report's data, without the page: parsing the server's JSON (with errors that
//! say what is wrong), the CSV export, chart series, the timeline's layout, the 3D path's
//! projection and the learning curve's points.

/** One score (see docs/assessment.md for every key). */
export interface Metric {
  key: string;
  label: string;
  unit: string;
  value: number;
  better: "lower" | "higher";
}

export interface Verdict {
  key: string;
  value: number;
  expert: number | null;
  limit: number;
  within: boolean;
}

export interface Phase {
  name: string;
  start_s: number | null;
  end_s: number | null;
}

export interface ProcedureError {
  kind: string;
  start_s: number;
  end_s: number;
  vessel: string;
  detail: string;
}

export interface ReportEvent {
  time_s: number;
  kind: string;
  message: string;
}

export interface Sample {
  time_s: number;
  tip_m: [number, number, number];
  along_route_m: number;
  inserted_m: number[];
  twist_rad: number[];
  wall_force_n: [number, number, number];
  fluoroscopy: boolean;
  contrast_ml: number;
  air_kerma_mgy: number;
  kap_gy_cm2: number;
  off_route_m: number;
  vessel: string;
}

export interface ReplayFrame {
  time_s: number;
  step: number;
  /** Each instrument's centerline, LPS mm. */
  instruments: [number, number, number][][];
}

export interface SessionReport {
  version: number;
  scene: string;
  duration_s: number;
  metrics: Metric[];
  verdicts: Verdict[];
  phases: Phase[];
  errors: ProcedureError[];
  events: ReportEvent[];
  samples: Sample[];
  frames: ReplayFrame[];
}

/** Parses a report; a report that is not what the page can show throws an Error naming why. */
export function parseReport(json: string): SessionReport {
  let value: unknown;
  try {
    value = JSON.parse(json);
  } catch (e) {
    throw new Error(`the report is not valid JSON (${e instanceof Error ? e.message : String(e)})`);
  }
  const r = value as Partial<SessionReport>;
  for (const field of ["metrics", "verdicts", "phases", "errors", "events", "samples", "frames"] as const) {
    if (!Array.isArray(r?.[field])) throw new Error(`the report has no ${field} list`);
  }
  if (typeof r.duration_s !== "number") throw new Error("the report has no duration");
  return r as SessionReport;
}

/** A CSV field, quoted when it needs to be (RFC 4180). */
function field(v: string | number | boolean | null | undefined): string {
  const text = v === null || v === undefined ? "" : String(v);
  return /[",\n]/.test(text) ? `"${text.replaceAll('"', '""')}"` : text;
}

/** The scores as CSV: one row per metric, with its expert value, limit and verdict. */
export function metricsCsv(report: SessionReport): string {
  const verdicts = new Map(report.verdicts.map((v) => [v.key, v]));
  const rows = [["key", "label", "unit", "value", "expert", "limit", "within_expert_range"].join(",")];
  for (const m of report.metrics) {
    const v = verdicts.get(m.key);
    rows.push(
      [m.key, m.label, m.unit, m.value, v?.expert ?? "", v?.limit ?? "", v ? v.within : ""].map(field).join(","),
    );
  }
  return `${rows.join("\n")}\n`;
}

/** The samples as CSV (time, tip, insertion and twist per instrument, forces, imaging, dose). */
export function samplesCsv(report: SessionReport): string {
  // A stack's loads and unloads change the number of instruments: a column per instrument
  // there ever was, empty while it was not in.
  const n = instrumentCount(report);
  const pad = (v: number[]) => Array.from({ length: n }, (_, i) => v[i] ?? null);
  const head = [
    "time_s",
    "tip_x_m",
    "tip_y_m",
    "tip_z_m",
    "along_route_m",
    ...Array.from({ length: n }, (_, i) => `inserted_${i}_m`),
    ...Array.from({ length: n }, (_, i) => `twist_${i}_rad`),
    "force_aortic_n",
    "force_cervical_n",
    "force_intracranial_n",
    "fluoroscopy",
    "contrast_ml",
    "air_kerma_mgy",
    "kap_gy_cm2",
    "off_route_m",
    "vessel",
  ];
  const rows = report.samples.map((s) =>
    [
      s.time_s,
      ...s.tip_m,
      s.along_route_m,
      ...pad(s.inserted_m),
      ...pad(s.twist_rad),
      ...s.wall_force_n,
      s.fluoroscopy ? 1 : 0,
      s.contrast_ml,
      s.air_kerma_mgy,
      s.kap_gy_cm2,
      s.off_route_m,
      s.vessel,
    ]
      .map(field)
      .join(","),
  );
  return `${[head.join(","), ...rows].join("\n")}\n`;
}

/** Parses a CSV made by `metricsCsv` back into key → value (for checks). */
export function parseMetricsCsv(csv: string): Map<string, number> {
  const out = new Map<string, number>();
  for (const line of csv.trim().split("\n").slice(1)) {
    const cells: string[] = [];
    let cell = "";
    let quoted = false;
    for (let i = 0; i < line.length; i++) {
      const c = line[i];
      if (quoted) {
        if (c === '"' && line[i + 1] === '"') {
          cell += '"';
          i++;
        } else if (c === '"') quoted = false;
        else cell += c;
      } else if (c === '"') quoted = true;
      else if (c === ",") {
        cells.push(cell);
        cell = "";
      } else cell += c;
    }
    cells.push(cell);
    out.set(cells[0], Number(cells[3]));
  }
  return out;
}

/** Chart series over the samples' times (uPlot's layout: x first). */
export interface Series {
  time: number[];
  /** Inserted length per instrument (mm; null while the instrument is not in). */
  inserted: (number | null)[][];
  /** Leading tip speed (mm/s), 0 at the first sample. */
  speed: number[];
  /** Wall force per class: aortic, cervical, intracranial (N). */
  force: number[][];
  /** 1 while exposing, else 0. */
  fluoroscopy: number[];
  /** Cumulative reference air kerma (mGy). */
  kerma: number[];
}

/** The most instruments any sample has. */
export function instrumentCount(report: SessionReport): number {
  return report.samples.reduce((n, s) => Math.max(n, s.inserted_m.length), 0);
}

export function series(report: SessionReport): Series {
  const s = report.samples;
  const n = instrumentCount(report);
  return {
    time: s.map((x) => x.time_s),
    inserted: Array.from({ length: n }, (_, i) =>
      s.map((x) => (x.inserted_m[i] === undefined ? null : x.inserted_m[i] * 1e3)),
    ),
    speed: s.map((x, k) => {
      if (k === 0) return 0;
      const p = s[k - 1];
      const d = Math.hypot(x.tip_m[0] - p.tip_m[0], x.tip_m[1] - p.tip_m[1], x.tip_m[2] - p.tip_m[2]);
      return (d * 1e3) / (x.time_s - p.time_s);
    }),
    force: [0, 1, 2].map((c) => s.map((x) => x.wall_force_n[c])),
    fluoroscopy: s.map((x) => (x.fluoroscopy ? 1 : 0)),
    kerma: s.map((x) => x.air_kerma_mgy),
  };
}

/** A bar or mark on the timeline, as fractions of the session's duration. */
export interface TimelineItem {
  kind: "phase" | "error" | "event";
  label: string;
  from: number;
  to: number;
  detail: string;
}

export function timeline(report: SessionReport): TimelineItem[] {
  const d = report.duration_s > 0 ? report.duration_s : 1;
  const at = (t: number) => Math.min(1, Math.max(0, t / d));
  const items: TimelineItem[] = [];
  for (const p of report.phases) {
    if (p.start_s === null || p.end_s === null) continue;
    items.push({
      kind: "phase",
      label: p.name,
      from: at(p.start_s),
      to: at(p.end_s),
      detail: `${p.name}: ${p.start_s.toFixed(1)}–${p.end_s.toFixed(1)} s`,
    });
  }
  for (const e of report.errors) {
    items.push({
      kind: "error",
      label: e.kind.replaceAll("_", " "),
      from: at(e.start_s),
      to: at(e.end_s),
      detail: `${e.start_s.toFixed(1)} s: ${e.detail}`,
    });
  }
  for (const e of report.events) {
    items.push({ kind: "event", label: e.kind, from: at(e.time_s), to: at(e.time_s), detail: `${e.time_s.toFixed(1)} s: ${e.message}` });
  }
  return items;
}

/** The replay frame to show at time `t` (s): the last at or before it. */
export function frameAt(report: SessionReport, t: number): number {
  let best = 0;
  report.frames.forEach((f, i) => {
    if (f.time_s <= t + 1e-9) best = i;
  });
  return best;
}

/**
 * Points (LPS mm) seen from azimuth `az` and elevation `el` (degrees) in an orthographic view:
 * screen x to the right, y up. Azimuth 0 looks from the front (anterior), so the patient's left
 * is on the screen's right, as on a frontal X-ray.
 */
export function project(p: [number, number, number], az: number, el: number): [number, number] {
  const a = (az * Math.PI) / 180;
  const e = (el * Math.PI) / 180;
  // Rotate about the superior axis, then tilt.
  const x = p[0] * Math.cos(a) + p[1] * Math.sin(a);
  const depth = -p[0] * Math.sin(a) + p[1] * Math.cos(a);
  const y = p[2] * Math.cos(e) - depth * Math.sin(e);
  return [x, y];
}

/** One trainee's history as the learning curve wants it. */
export interface HistoryPoint {
  sessionId: string;
  createdUnixS: number;
  sceneName: string;
  assessed: boolean;
  metrics: Record<string, number>;
  expert: Record<string, number>;
}

/** The learning curve of `key` on `scene`: (attempt number from 1, value), assessed sessions in order. */
export function learningCurve(history: HistoryPoint[], scene: string, key: string): [number, number][] {
  return history
    .filter((h) => h.sceneName === scene && h.assessed && Number.isFinite(h.metrics[key]))
    .sort((a, b) => a.createdUnixS - b.createdUnixS)
    .map((h, i) => [i + 1, h.metrics[key]]);
}
