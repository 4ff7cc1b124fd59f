//! The heads-up display's figures: formatting and the wall-force warning.
import type { DeviceState, Metrics } from "./gen/cathlab/v1/simulator_pb.js";

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
  fluoroscopy: string;
  contrast: string;
  wallForce: string;
  warning: boolean;
  target: string;
}

export function hudLines(state: DeviceState | undefined, metrics: Metrics | undefined, target: string): HudLines {
  const force = state ? largestWallForce(state) : 0;
  const reached = metrics?.targetReached ?? false;
  return {
    inserted: state ? `${state.insertedMm.toFixed(1)} mm` : "—",
    fluoroscopy: clock(metrics?.fluoroscopyTimeS ?? 0),
    contrast: `${(metrics?.contrastVolumeMl ?? 0).toFixed(1)} mL`,
    wallForce: `${(force * 1000).toFixed(0)} mN`,
    warning: force > WALL_FORCE_WARNING_N,
    target: target
      ? reached
        ? `${target} reached at ${clock(metrics?.targetReachedAtS ?? 0)}`
        : target
      : "—",
  };
}

/** The metric rows a card shows. */
export function metricRows(m: Metrics | undefined): [string, string][] {
  return [
    ["Time", clock(m?.procedureTimeS ?? 0)],
    ["Fluoro", clock(m?.fluoroscopyTimeS ?? 0)],
    ["Contrast", `${(m?.contrastVolumeMl ?? 0).toFixed(1)} mL`],
    ["Max wall force", `${((m?.maxWallForceN ?? 0) * 1000).toFixed(0)} mN`],
    ["Tip path", `${(m?.tipPathLengthMm ?? 0).toFixed(0)} mm`],
    ["Target", m?.targetReached ? `reached at ${clock(m.targetReachedAtS)}` : "not yet"],
    ["Resets", String(m?.divergenceResets ?? 0)],
  ];
}

