import { create } from "@bufbuild/protobuf";
import { describe, expect, it } from "vitest";
import { InstrumentStateSchema, PushLimit } from "./gen/cathlab/v1/simulator_pb.js";
import { mm, relative, shortName, stackLines } from "./stack.js";

describe("stack panel", () => {
  it("writes millimetres whole above 10 mm, to 0.1 mm below, with a true minus", () => {
    expect(mm(312.4)).toBe("312 mm");
    expect(mm(4.26)).toBe("4.3 mm");
    expect(mm(-4.26)).toBe("−4.3 mm");
    expect(mm(-0.01)).toBe("0.0 mm");
  });
  it("names instruments by the catalogue's kind word", () => {
    expect(shortName('0.014" microwire, 45 deg angled tip (Synchro / Traxcess class), 200 cm')).toBe("microwire");
    expect(shortName('6F guide catheter, 0.071" lumen, straight tip (Envoy / Neuron class), 90 cm')).toBe("guide catheter");
    expect(shortName("5F vertebral diagnostic catheter, 100 cm")).toBe("catheter");
    expect(shortName('Microcatheter 0.017" 150 cm')).toBe("microcatheter");
    expect(shortName("my device")).toBe("my device");
  });
  it("says where a tip is against the one around it", () => {
    expect(relative("a wire", "a catheter", 24)).toBe("wire 24 mm out of the catheter");
    expect(relative("a wire", "a catheter", -3.04)).toBe("wire 3.0 mm inside the catheter");
    expect(relative("a wire", "a catheter", 0.2)).toBe("wire tip level with the catheter tip");
  });
  it("gives one line per instrument, outermost first, with its hand's force and limit", () => {
    const guide = create(InstrumentStateSchema, { name: "6F guide catheter", insertedMm: 290, axialForceN: 0.5 });
    const micro = create(InstrumentStateSchema, {
      name: "microcatheter",
      insertedMm: 340,
      beyondOuterMm: 50,
      axialForceN: 0.125,
      pushLimit: PushLimit.FORCE,
    });
    const wire = create(InstrumentStateSchema, { name: "0.014 microwire", insertedMm: 364, beyondOuterMm: 24 });
    const lines = stackLines([guide, micro, wire]);
    expect(lines.map((l) => l.relative)).toEqual([
      "in from the entry",
      "microcatheter 50 mm out of the guide catheter",
      "microwire 24 mm out of the microcatheter",
    ]);
    expect(lines.map((l) => l.inserted)).toEqual(["290 mm", "340 mm", "364 mm"]);
    expect(lines[1].force).toBe("0.13 N · force limit");
    expect(lines[2].force).toBe("0.00 N");
  });
});
