import { create } from "@bufbuild/protobuf";
import { describe, expect, it } from "vitest";
import { DeviceStateSchema, MetricsSchema } from "./gen/cathlab/v1/simulator_pb.js";
import { WALL_FORCE_WARNING_N, clock, hudLines, largestWallForce, metricRows } from "./hud.js";

const contact = (x: number, y: number, z: number) => ({ force: { x, y, z } });

describe("HUD", () => {
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
  it("shows fluoroscopy time, contrast and when the target was reached", () => {
    const metrics = create(MetricsSchema, {
      fluoroscopyTimeS: 75.2,
      contrastVolumeMl: 12.25,
      targetReached: true,
      targetReachedAtS: 130,
    });
    const lines = hudLines(undefined, metrics, "lcca");
    expect(lines).toMatchObject({ inserted: "—", fluoroscopy: "1:15", contrast: "12.3 mL", target: "lcca reached at 2:10" });
    expect(Object.fromEntries(metricRows(metrics))).toMatchObject({ Fluoro: "1:15", Target: "reached at 2:10" });
  });
});
