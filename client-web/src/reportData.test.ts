import { describe, expect, it } from "vitest";
import {
  type SessionReport,
  frameAt,
  learningCurve,
  metricsCsv,
  parseMetricsCsv,
  parseReport,
  project,
  samplesCsv,
  series,
  timeline,
} from "./reportData.js";

const sample = (t: number, x: number, fluoroscopy: boolean) => ({
  time_s: t,
  tip_m: [x, 0, 0] as [number, number, number],
  along_route_m: x,
  inserted_m: [x, x + 0.01],
  twist_rad: [0, 0.5],
  wall_force_n: [0.1, 0, 0.3] as [number, number, number],
  fluoroscopy,
  contrast_ml: 0,
  air_kerma_mgy: t,
  kap_gy_cm2: 0.1 * t,
  off_route_m: 0,
  vessel: "left common carotid, \"cervical\"",
});

const report: SessionReport = {
  version: 1,
  scene: "arch",
  duration_s: 2,
  metrics: [
    { key: "procedure_time_s", label: "Procedure time", unit: "s", value: 2, better: "lower" },
    { key: "sparc", label: "Smoothness, \"SPARC\"", unit: "", value: -1.5, better: "higher" },
  ],
  verdicts: [{ key: "procedure_time_s", value: 2, expert: 1.5, limit: 2.25, within: true }],
  phases: [
    { name: "access", start_s: 0, end_s: 1 },
    { name: "never", start_s: null, end_s: null },
    { name: "arch", start_s: 1, end_s: 2 },
  ],
  errors: [{ kind: "off_route", start_s: 0.5, end_s: 1, vessel: "LCCA", detail: "20 mm off" }],
  events: [{ time_s: 1.5, kind: "target_reached", message: "reached" }],
  samples: [sample(0, 0, false), sample(1, 0.01, true), sample(2, 0.03, true)],
  frames: [
    { time_s: 0, step: 0, instruments: [[[0, 0, 0], [1, 0, 0]]] },
    { time_s: 1, step: 500, instruments: [[[0, 0, 0], [2, 0, 0]]] },
  ],
};

describe("the report's data", () => {
  it("exports scores as CSV that reads back to the same values, quoting what needs it", () => {
    const csv = metricsCsv(report);
    expect(csv.split("\n")[0]).toBe("key,label,unit,value,expert,limit,within_expert_range");
    expect(csv).toContain('"Smoothness, ""SPARC"""');
    expect(csv).toContain("procedure_time_s,Procedure time,s,2,1.5,2.25,true");
    const back = parseMetricsCsv(csv);
    expect(back.get("procedure_time_s")).toBe(2);
    expect(back.get("sparc")).toBe(-1.5);
  });

  it("pads the instruments a stack loaded later", () => {
    const grown = { ...report, samples: [...report.samples, { ...sample(3, 0.04, true), inserted_m: [0.04, 0.05, 0.06], twist_rad: [0, 0, 0] }] };
    const lines = samplesCsv(grown).trim().split("\n");
    expect(lines[0]).toContain("inserted_2_m");
    expect(lines[1].split(",")).toHaveLength(lines[4].split(",").length);
    expect(series(grown).inserted[2]).toEqual([null, null, null, 60]);
  });

  it("exports samples with a column per instrument", () => {
    const lines = samplesCsv(report).trim().split("\n");
    expect(lines).toHaveLength(4);
    expect(lines[0]).toContain("inserted_0_m,inserted_1_m,twist_0_rad,twist_1_rad");
    expect(lines[2].startsWith("1,0.01,0,0,0.01,0.01,0.02,0,0.5,0.1,0,0.3,1,")).toBe(true);
  });

  it("derives speeds in mm/s and insertions in mm", () => {
    const s = series(report);
    expect(s.speed[0]).toBe(0);
    expect(s.speed[1]).toBeCloseTo(10);
    expect(s.speed[2]).toBeCloseTo(20);
    expect(s.inserted[1][2]).toBeCloseTo(40);
    expect(s.fluoroscopy).toEqual([0, 1, 1]);
  });

  it("lays the timeline out as fractions, leaving phases never reached out", () => {
    const items = timeline(report);
    expect(items.filter((i) => i.kind === "phase").map((i) => [i.from, i.to])).toEqual([
      [0, 0.5],
      [0.5, 1],
    ]);
    const error = items.find((i) => i.kind === "error")!;
    expect([error.from, error.to, error.label]).toEqual([0.25, 0.5, "off route"]);
  });

  it("finds the frame at a time and projects frontal views with the patient's left on the right", () => {
    expect(frameAt(report, 0.99)).toBe(0);
    expect(frameAt(report, 1.5)).toBe(1);
    expect(project([10, 5, 3], 0, 0)).toEqual([10, 3]);
    const side = project([10, 5, 3], 90, 0);
    expect(side[0]).toBeCloseTo(5);
  });

  it("draws the learning curve of a scene from its assessed sessions in order", () => {
    const h = (id: string, t: number, scene: string, value: number | undefined) => ({
      sessionId: id,
      createdUnixS: t,
      sceneName: scene,
      assessed: value !== undefined,
      metrics: (value === undefined ? {} : { procedure_time_s: value }) as Record<string, number>,
      expert: {},
    });
    const curve = learningCurve(
      [h("b", 20, "arch", 30), h("a", 10, "arch", 50), h("c", 30, "other", 5), h("d", 40, "arch", undefined)],
      "arch",
      "procedure_time_s",
    );
    expect(curve).toEqual([
      [1, 50],
      [2, 30],
    ]);
  });

  it("names what is wrong with a report it cannot show", () => {
    expect(() => parseReport("{not json")).toThrow(/not valid JSON/);
    expect(() => parseReport('{"metrics": []}')).toThrow(/no verdicts list/);
    expect(parseReport(JSON.stringify(report)).scene).toBe("arch");
  });
});
