import { create } from "@bufbuild/protobuf";
import { describe, expect, it } from "vitest";
import { DeviceStateSchema, MetricsSchema, PushLimit } from "./gen/cathlab/v1/simulator_pb.js";
import {
  WALL_FORCE_WARNING_N,
  clock,
  doseLine,
  hudLines,
  largestWallForce,
  metricRows,
  resetsLine,
  twistLine,
} from "./hud.js";

const contact = (x: number, y: number, z: number) => ({ force: { x, y, z } });

describe("HUD", () => {
  it("reads the twist in whole degrees with its sign", () => {
    expect(twistLine(0)).toBe("0°");
    expect(twistLine(89.6)).toBe("+90°");
    expect(twistLine(-450.2)).toBe("−450°");
    expect(hudLines(create(DeviceStateSchema, { twistDeg: 30 }), undefined, "").twist).toBe("+30°");
  });
  it("shows the cumulative reference air kerma and DAP as a dose display does", () => {
    expect(doseLine({ referenceAirKermaMgy: 0, kermaAreaProductGyCm2: 0 })).toBe("Ka,r 0.00 mGy · DAP 0.00 Gy·cm²");
    expect(doseLine({ referenceAirKermaMgy: 3.456, kermaAreaProductGyCm2: 0.789 })).toBe(
      "Ka,r 3.46 mGy · DAP 0.79 Gy·cm²",
    );
    expect(doseLine({ referenceAirKermaMgy: 123.4, kermaAreaProductGyCm2: 45.67 })).toBe(
      "Ka,r 123 mGy · DAP 45.7 Gy·cm²",
    );
  });
  it("formats times as m:ss", () => {
    expect(clock(0)).toBe("0:00");
    expect(clock(59.99)).toBe("0:59");
    expect(clock(61)).toBe("1:01");
    expect(clock(-3)).toBe("0:00");
  });
  it("takes the largest contact force's magnitude and warns above the threshold", () => {
    const state = create(DeviceStateSchema, {
      insertedMm: 123.456,
      contacts: [contact(0.03, 0.04, 0), contact(0, 0, -0.02)],
    });
    expect(largestWallForce(state)).toBeCloseTo(0.05, 15);
    let lines = hudLines(state, undefined, "");
    expect(lines).toMatchObject({ inserted: "123.5 mm", wallForce: "50 mN", warning: false, target: "—" });
    const hard = create(DeviceStateSchema, { contacts: [contact(0, WALL_FORCE_WARNING_N * 1.01, 0)] });
    lines = hudLines(hard, undefined, "lcca");
    expect(lines.warning).toBe(true);
    expect(lines.target).toBe("lcca");
  });
  it("times the target from the attempt's start and counts the trainee's resets apart", () => {
    const m = create(MetricsSchema, {
      targetReached: true,
      targetReachedAtS: 130,
      attemptStartedAtS: 100,
      operatorResets: 2,
      divergenceResets: 0,
    });
    expect(hudLines(undefined, m, "rva").target).toBe("rva reached in 0:30");
    expect(hudLines(undefined, m, "rva").reached).toBe(true);
    const going = create(MetricsSchema, { targetRemainingMm: 123.4 });
    expect(hudLines(undefined, going, "lcca")).toMatchObject({ target: "lcca · 123 mm", reached: false });
    expect(hudLines(undefined, going, "lcca", false).target).toBe("lcca");
    expect(Object.fromEntries(metricRows(going))).toMatchObject({ Target: "123 mm to go" });
    expect(Object.fromEntries(metricRows(m))).toMatchObject({ Target: "reached in 0:30", Resets: "2" });
    m.divergenceResets = 1;
    expect(resetsLine(m)).toBe("2 (+1 after divergence)");
  });
  it("grades the reperfusion only in a scene with clots", () => {
    expect(Object.keys(Object.fromEntries(metricRows(create(MetricsSchema, {}))))).not.toContain("eTICI");
    const clotted = create(MetricsSchema, { reperfusion: { fraction: 0.7, etici: "2b67" } });
    expect(Object.fromEntries(metricRows(clotted))).toMatchObject({ eTICI: "2b67 (70 %)" });
    expect(Object.keys(Object.fromEntries(metricRows(clotted)))).not.toContain("Passes");
  });

  it("shows the thrombectomy's passes, emboli, grip and time to reperfusion", () => {
    const engaged = create(MetricsSchema, {
      reperfusion: { fraction: 0.2, etici: "2a" },
      thrombectomy: { passes: 0, gripN: 0.238 },
    });
    const rows = Object.fromEntries(metricRows(engaged));
    expect(rows).toMatchObject({ Passes: "0", "Stent grip": "0.24 N" });
    expect(rows).not.toHaveProperty("Emboli");
    expect(rows).not.toHaveProperty("Reperfused at");
    const done = create(MetricsSchema, {
      reperfusion: { fraction: 1, etici: "3" },
      thrombectomy: { passes: 1, firstPassEffect: true, emboli: 1, reperfusedAtS: 47.3 },
    });
    expect(Object.fromEntries(metricRows(done))).toMatchObject({
      Passes: "1 · first-pass effect",
      Emboli: "1",
      "Reperfused at": clock(47.3),
    });
  });
  it("shows fluoroscopy time, contrast and when the target was reached", () => {
    const metrics = create(MetricsSchema, {
      fluoroscopyTimeS: 75.2,
      contrastVolumeMl: 12.25,
      targetReached: true,
      targetReachedAtS: 130,
    });
    const lines = hudLines(undefined, metrics, "lcca");
    expect(lines).toMatchObject({ inserted: "—", fluoroscopy: "1:15", contrast: "12.3 mL", target: "lcca reached in 2:10" });
    expect(Object.fromEntries(metricRows(metrics))).toMatchObject({ Fluoro: "1:15", Target: "reached in 2:10" });
  });
  it("says what holds a push back and when fidelity is reduced", () => {
    const held = create(DeviceStateSchema, {
      insertedMm: 412.34,
      pushLimit: PushLimit.FORCE,
      pushForceLimitN: 1.93,
      fidelityLevel: 2,
    });
    expect(hudLines(held, undefined, "").inserted).toBe("412.3 mm · held 1.9 N · lo-fi 2");
    const hub = create(DeviceStateSchema, { insertedMm: 1350, pushLimit: PushLimit.LENGTH });
    expect(hudLines(hub, undefined, "").inserted).toBe("1350.0 mm · hub");
  });
});
