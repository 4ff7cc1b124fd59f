import { describe, expect, it } from "vitest";
import { timelineRows } from "./timeline.js";

const ev = (timeS: number, kind: string, message: string) => ({ timeS, kind, message });

describe("timeline", () => {
  it("folds each fluoroscopy run into one line with its duration, newest first", () => {
    const rows = timelineRows([
      ev(0.5, "imaging", "fluoroscopy on"),
      ev(1.0, "command", "push"),
      ev(2.9, "imaging", "fluoroscopy off"),
      ev(3.0, "reset", "scene reset: a new attempt"),
      ev(4.0, "imaging", "fluoroscopy on"),
      ev(4.2, "imaging", "fluoroscopy off"),
      ev(5.0, "imaging", "fluoroscopy on"),
    ]);
    expect(rows.map((r) => `${r.timeS} ${r.message}`)).toEqual([
      "5 fluoroscopy on",
      "4 fluoroscopy 0.2 s",
      "3 scene reset: a new attempt",
      "1 push",
      "0.5 fluoroscopy 2.4 s",
    ]);
  });
  it("keeps other imaging events and an off without an on", () => {
    const rows = timelineRows([ev(1, "imaging", "DSA run 1 started"), ev(2, "imaging", "fluoroscopy off")]);
    expect(rows.map((r) => r.message)).toEqual(["fluoroscopy 0.0 s", "DSA run 1 started"]);
  });
});
