import { describe, expect, it } from "vitest";
import {
  DEAD_ZONE,
  DriveCommands,
  PUSH_MM_S,
  TWIST_DEG_S,
  combine,
  deadZone,
  driveKey,
  gamepadHands,
  isDriveKey,
  keyboardDemand,
  keyboardHands,
} from "./controls.js";

describe("keyboard", () => {
  it("takes the arrows, W A S D and F as drive keys, in either case, and nothing else", () => {
    for (const k of ["ArrowUp", "ArrowDown", "ArrowLeft", "ArrowRight", "f", "F", "w", "A", "s", "D"])
      expect(isDriveKey(k)).toBe(true);
    for (const k of ["Tab", "Enter", " ", "PageUp", "g", "1", "q", "Shift"]) expect(isDriveKey(k)).toBe(false);
    expect(driveKey("W")).toBe("w");
    expect(driveKey("ArrowUp")).toBe("ArrowUp");
  });
  it("gives W/S/A/D to the left hand and the arrows to the right, each independent", () => {
    expect(keyboardHands(new Set(["w", "ArrowLeft"]))).toEqual({
      left: { push: 1, twist: 0 },
      right: { push: 0, twist: -1 },
    });
    expect(keyboardHands(new Set(["s", "d", "ArrowUp"]))).toEqual({
      left: { push: -1, twist: 1 },
      right: { push: 1, twist: 0 },
    });
    expect(keyboardHands(new Set(["w", "s", "a"]))).toEqual({ left: { push: 0, twist: -1 }, right: { push: 0, twist: 0 } });
  });
  it("maps the arrows to push/pull and twist, opposite keys cancelling", () => {
    expect(keyboardDemand(new Set(["ArrowUp"]))).toEqual({ push: 1, twist: 0 });
    expect(keyboardDemand(new Set(["ArrowDown", "ArrowLeft"]))).toEqual({ push: -1, twist: -1 });
    expect(keyboardDemand(new Set(["ArrowUp", "ArrowDown", "ArrowRight"]))).toEqual({ push: 0, twist: 1 });
    expect(keyboardDemand(new Set(["a", "F"]))).toEqual({ push: 0, twist: 0 });
  });
});

describe("gamepad", () => {
  it("ignores the dead zone and reaches full scale at full deflection", () => {
    expect(deadZone(DEAD_ZONE * 0.99)).toBe(0);
    expect(deadZone(-DEAD_ZONE)).toBe(0);
    expect(deadZone(1)).toBe(1);
    expect(deadZone(-1)).toBe(-1);
    expect(deadZone(1.3)).toBe(1);
    expect(deadZone(Number.NaN)).toBe(0);
    // Continuous at the edge of the zone and linear beyond it.
    expect(deadZone(DEAD_ZONE + 1e-9)).toBeCloseTo(0, 6);
    expect(deadZone((1 + DEAD_ZONE) / 2)).toBeCloseTo(0.5, 12);
  });
  it("drives the left hand with the left stick and the right hand with the right stick and D-pad", () => {
    const none = Array(16).fill(false);
    const idle = { push: 0, twist: 0 };
    // Up (axis negative) pushes; sideways twists.
    expect(gamepadHands([0, -1, 0, 0], none)).toEqual({ left: { push: 1, twist: 0 }, right: idle });
    expect(gamepadHands([1, 1, 0, 0], none)).toEqual({ left: { push: -1, twist: 1 }, right: idle });
    expect(gamepadHands([0, 0, -1, -1], none)).toEqual({ left: idle, right: { push: 1, twist: -1 } });
    const dpad = none.slice();
    dpad[12] = true; // up
    dpad[14] = true; // left
    expect(gamepadHands([0, 0, 0, 0], dpad)).toEqual({ left: idle, right: { push: 1, twist: -1 } });
    expect(gamepadHands([], [])).toEqual({ left: idle, right: idle });
  });
  it("combines sources with each axis clamped", () => {
    expect(combine({ push: 1, twist: 0.5 }, { push: 1, twist: -0.25 })).toEqual({ push: 1, twist: 0.25 });
  });
});

describe("drive commands", () => {
  it("sends an insertion speed or twist rate only when it changes, scaled to mm/s and deg/s", () => {
    const drive = new DriveCommands();
    const [push] = drive.next({ push: 1, twist: 0 });
    expect(push.kind.case).toBe("insertion");
    expect(push.kind.case === "insertion" && push.kind.value.mode).toEqual({ case: "velocityMmS", value: PUSH_MM_S });
    expect(drive.next({ push: 1, twist: 0 })).toHaveLength(0);
    const both = drive.next({ push: 0, twist: -1 });
    expect(both.map((c) => c.kind.case)).toEqual(["insertion", "twist"]);
    const twist = both[1];
    expect(twist.kind.case === "twist" && twist.kind.value.mode).toEqual({ case: "rateDegS", value: -TWIST_DEG_S });
    // Letting go stops the device: a zero speed is sent, not silence.
    const stop = drive.next({ push: 0, twist: 0 });
    expect(stop).toHaveLength(1);
    expect(stop[0].kind.case === "twist" && stop[0].kind.value.mode).toEqual({ case: "rateDegS", value: 0 });
  });
  it("names its instrument, and a regrip stops the old one before taking the new", () => {
    expect(new DriveCommands().next({ push: 1, twist: 0 })[0].instrument).toBeUndefined();
    const hand = new DriveCommands(1);
    const [push] = hand.next({ push: 1, twist: 0 });
    expect(push.instrument).toBe(1);
    const stop = hand.regrip(0);
    expect(stop).toHaveLength(1);
    expect(stop[0].instrument).toBe(1);
    expect(stop[0].kind.case === "insertion" && stop[0].kind.value.mode).toEqual({ case: "velocityMmS", value: 0 });
    expect(hand.repeat()).toHaveLength(0);
    expect(hand.next({ push: 0, twist: 1 })[0].instrument).toBe(0);
    // A still hand regrips silently.
    expect(new DriveCommands(2).regrip(1)).toHaveLength(0);
  });
  it("sends speeds in hold mode and repeats only those in force", () => {
    const drive = new DriveCommands();
    expect(drive.repeat()).toHaveLength(0);
    const [push] = drive.next({ push: -1, twist: 0 });
    expect(push.kind.case === "insertion" && push.kind.value.hold).toBe(true);
    const again = drive.repeat();
    expect(again).toHaveLength(1);
    expect(again[0].kind.case === "insertion" && again[0].kind.value.mode).toEqual({
      case: "velocityMmS",
      value: -PUSH_MM_S,
    });
    drive.next({ push: 0, twist: 0.5 });
    expect(drive.repeat().map((c) => c.kind.case)).toEqual(["twist"]);
    drive.next({ push: 0, twist: 0 });
    expect(drive.repeat()).toHaveLength(0);
  });
});
