//! The target marker: the target vessel's outline (sent by the server in image fractions)
//! drawn over the subtraction and roadmap images, unless the session's guidance hides it.
import { ImagingMode, type XrayFrame } from "./gen/cathlab/v1/simulator_pb.js";

/** The modes that show the marker: the ones with vessels to read it against. */
export function showsMarker(mode: ImagingMode): boolean {
  return mode === ImagingMode.SUBTRACTION || mode === ImagingMode.ROADMAP;
}

/** SVG polyline points ("x,y x,y …" in a unit viewBox) from flat (x, y) fraction pairs;
 *  an odd trailing value or a non-finite pair is dropped. */
export function polylinePoints(outline: ArrayLike<number>): string {
  const pairs: string[] = [];
  for (let i = 0; i + 1 < outline.length; i += 2) {
    const x = outline[i];
    const y = outline[i + 1];
    if (Number.isFinite(x) && Number.isFinite(y)) pairs.push(`${x.toFixed(4)},${y.toFixed(4)}`);
  }
  return pairs.join(" ");
}

/** Draws `frame`'s target outline into `svg` (a unit viewBox laid over the image), with the
 *  goal at its end and `name` beside it; hides it in other modes or without an outline. */
export function drawMarker(svg: SVGSVGElement, frame: Pick<XrayFrame, "mode" | "targetOutline">, name: string) {
  const points = polylinePoints(frame.targetOutline);
  const visible = showsMarker(frame.mode) && points.length > 0;
  svg.dataset.visible = String(visible);
  svg.style.display = visible ? "" : "none";
  if (!visible) return;
  svg.querySelector("polyline")?.setAttribute("points", points);
  const n = frame.targetOutline.length;
  const goal = svg.querySelector("circle");
  goal?.setAttribute("cx", String(frame.targetOutline[n - 2]));
  goal?.setAttribute("cy", String(frame.targetOutline[n - 1]));
  const label = svg.parentElement?.querySelector<HTMLElement>("#target-label");
  if (label) {
    label.textContent = name;
    label.style.left = `${(frame.targetOutline[n - 2] * 100).toFixed(2)}%`;
    label.style.top = `${(frame.targetOutline[n - 1] * 100).toFixed(2)}%`;
  }
}
