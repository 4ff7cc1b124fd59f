//! The heads-up display's figures: formatting and the wall-force warning.
import { type DeviceState, type Metrics, PushLimit, type XrayFrame } from "./gen/cathlab/v1/simulator_pb.js";

/** Wall force (N) above which the HUD warns: a training threshold (a tenth of a newton on
 *  a wire tip is a hard push), not a clinical limit. */
export const WALL_FORCE_WARNING_N = 0.1;

/** Largest current wall contact force (N), 0 without contact. */
export function largestWallForce(state: Pick<DeviceState, "contacts">): number {
  let largest = 0;
  for (const c of state.contacts) {
    const f = c.force;
    if (f) largest = Math.max(largest, Math.hypot(f.x, f.y, f.z));
  }
  return largest;
}

/** m:ss (seconds rounded down). */
export function clock(seconds: number): string {
  const s = Math.max(0, Math.floor(seconds));
  return `${Math.floor(s / 60)}:${String(s % 60).padStart(2, "0")}`;
}

/** The HUD lines, in the order shown. */
export interface HudLines {
  inserted: string;
  twist: string;
  fluoroscopy: string;
  contrast: string;
  wallForce: string;
  warning: boolean;
  target: string;
  /** The target reached in this attempt (the HUD styles it as a success). */
  reached: boolean;
}

/** The HUD's lines; `showDistance` false (an assessment) leaves the remaining distance out. */
export function hudLines(
  state: DeviceState | undefined,
  metrics: Metrics | undefined,
  target: string,
  showDistance = true,
): HudLines {
  const force = state ? largestWallForce(state) : 0;
  const reached = metrics?.targetReached ?? false;
  return {
    inserted: state ? insertedLine(state) : "—",
    twist: state ? twistLine(state.twistDeg) : "—",
    fluoroscopy: clock(metrics?.fluoroscopyTimeS ?? 0),
    contrast: `${(metrics?.contrastVolumeMl ?? 0).toFixed(1)} mL`,
    wallForce: `${(force * 1000).toFixed(0)} mN`,
    warning: force > WALL_FORCE_WARNING_N,
    target: target
      ? reached
        ? `${target} reached in ${clock(attemptTime(metrics))}`
        : metrics && showDistance
          ? `${target} · ${metrics.targetRemainingMm.toFixed(0)} mm`
          : target
      : "—",
    reached,
  };
}

/** The inserted length, with what holds the push back and whether the server has lowered
 *  the fidelity to keep up. */
export function insertedLine(
  state: Pick<DeviceState, "insertedMm" | "pushLimit" | "pushForceLimitN" | "fidelityLevel">,
): string {
  let line = `${state.insertedMm.toFixed(1)} mm`;
  // Short, so the HUD keeps its one line per figure (the events say the rest).
  if (state.pushLimit === PushLimit.FORCE) line += ` · held ${state.pushForceLimitN.toFixed(1)} N`;
  else if (state.pushLimit === PushLimit.LENGTH) line += " · hub";
  if (state.fidelityLevel > 0) line += ` · lo-fi ${state.fidelityLevel}`;
  return line;
}

/** The metric rows a card shows. */
export function metricRows(m: Metrics | undefined): [string, string][] {
  return [
    ["Time", clock(m?.procedureTimeS ?? 0)],
    ["Fluoro", clock(m?.fluoroscopyTimeS ?? 0)],
    ["Contrast", `${(m?.contrastVolumeMl ?? 0).toFixed(1)} mL`],
    ["Max wall force", `${((m?.maxWallForceN ?? 0) * 1000).toFixed(0)} mN`],
    ["Tip path", `${(m?.tipPathLengthMm ?? 0).toFixed(0)} mm`],
    [
      "Target",
      m?.targetReached
        ? `reached in ${clock(attemptTime(m))}`
        : `${(m?.targetRemainingMm ?? 0).toFixed(0)} mm to go`,
    ],
    ["Resets", resetsLine(m)],
    ...reperfusionRows(m),
  ];
}

/** The reperfusion row, in a scene with clots: the eTICI grade and the reperfused share of
 *  the occluded territory. */
export function reperfusionRows(m: Metrics | undefined): [string, string][] {
  const r = m?.reperfusion;
  const rows: [string, string][] = r ? [["eTICI", `${r.etici} (${Math.round(r.fraction * 100)} %)`]] : [];
  const t = m?.thrombectomy;
  if (t) {
    const fpe = t.firstPassEffect ? " · first-pass effect" : "";
    rows.push(["Passes", `${t.passes}${fpe}`]);
    if (t.emboli > 0) rows.push(["Emboli", `${t.emboli}`]);
    if (t.gripN > 0) rows.push(["Stent grip", `${t.gripN.toFixed(2)} N`]);
    if (t.reperfusedAtS !== undefined) rows.push(["Reperfused at", clock(t.reperfusedAtS)]);
  }
  return rows;
}


/** The dose display of an angio system's monitor: cumulative air kerma at the interventional
 *  reference point and kerma–area product, from the latest frame. */
export function doseLine(frame: Pick<XrayFrame, "referenceAirKermaMgy" | "kermaAreaProductGyCm2">): string {
  const kerma = frame.referenceAirKermaMgy;
  const dap = frame.kermaAreaProductGyCm2;
  const mgy = kerma < 10 ? kerma.toFixed(2) : kerma.toFixed(0);
  const gycm2 = dap < 10 ? dap.toFixed(2) : dap.toFixed(1);
  return `Ka,r ${mgy} mGy · DAP ${gycm2} Gy·cm²`;
}

/** The operator's twist at the hub (degrees, clockwise positive as seen from the operator),
 *  with whole turns counted: "+450°" reads as one and a quarter turns clockwise. */
export function twistLine(degrees: number): string {
  const rounded = Math.round(degrees);
  const sign = rounded > 0 ? "+" : rounded < 0 ? "−" : "";
  return `${sign}${Math.abs(rounded)}°`;
}

/** Time from the current attempt's start (the session's, or the last reset's) to reaching the
 *  target (s). */
export function attemptTime(m: Pick<Metrics, "targetReachedAtS" | "attemptStartedAtS"> | undefined): number {
  return Math.max(0, (m?.targetReachedAtS ?? 0) - (m?.attemptStartedAtS ?? 0));
}

/** The trainee's resets, and the simulator's own after a divergence when there were any. */
export function resetsLine(m: Pick<Metrics, "operatorResets" | "divergenceResets"> | undefined): string {
  const own = m?.operatorResets ?? 0;
  const diverged = m?.divergenceResets ?? 0;
  return diverged > 0 ? `${own} (+${diverged} after divergence)` : String(own);
}
