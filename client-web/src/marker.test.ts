import { describe, expect, it } from "vitest";
import { ImagingMode } from "./gen/cathlab/v1/simulator_pb.js";
import { polylinePoints, showsMarker } from "./marker.js";

describe("the target marker", () => {
  it("turns flat fraction pairs into SVG points, dropping a dangling value and NaN pairs", () => {
    expect(polylinePoints([0.5, 0.25, 0.1, 0.9, 0.3])).toBe("0.5000,0.2500 0.1000,0.9000");
    expect(polylinePoints([Number.NaN, 0.1, 0.2, 0.3])).toBe("0.2000,0.3000");
    expect(polylinePoints([])).toBe("");
  });
  it("shows on subtraction and roadmap images only", () => {
    expect(showsMarker(ImagingMode.ROADMAP)).toBe(true);
    expect(showsMarker(ImagingMode.SUBTRACTION)).toBe(true);
    expect(showsMarker(ImagingMode.FLUOROSCOPY)).toBe(false);
  });
});
