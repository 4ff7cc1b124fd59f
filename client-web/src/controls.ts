//! Trainee input: keyboard, on-screen buttons and a gamepad combined into one push/pull speed
//! (mm/s) and twist rate (deg/s), sent as commands only when they change.
import { create } from "@bufbuild/protobuf";
import { type Command, CommandSchema } from "./gen/cathlab/v1/simulator_pb.js";

/** Full-stick push/pull speed (mm/s) and twist rate (deg/s). */
export const PUSH_MM_S = 20;
export const TWIST_DEG_S = 90;
/** Gamepad stick dead zone (fraction of full deflection). */
export const DEAD_ZONE = 0.15;

/** One input source's demand, each axis in −1..1 (push +, clockwise twist +). */
export interface Demand {
  push: number;
  twist: number;
}

/** The keys that drive the device (arrows) and the fluoroscopy pedal (F). */
export function isDriveKey(key: string): boolean {
  return key === "ArrowUp" || key === "ArrowDown" || key === "ArrowLeft" || key === "ArrowRight" || key === "f" || key === "F";
}

/** Keys held → demand: ↑ pushes, ↓ pulls, → twists clockwise, ← counter-clockwise. */
export function keyboardDemand(held: ReadonlySet<string>): Demand {
  const axis = (plus: string, minus: string) => (held.has(plus) ? 1 : 0) - (held.has(minus) ? 1 : 0);
  return { push: axis("ArrowUp", "ArrowDown"), twist: axis("ArrowRight", "ArrowLeft") };
}

/** A stick axis with a dead zone, rescaled so the output starts at 0 at its edge. */
export function deadZone(value: number, zone = DEAD_ZONE): number {
  if (!Number.isFinite(value) || Math.abs(value) <= zone) return 0;
  return (Math.sign(value) * (Math.min(Math.abs(value), 1) - zone)) / (1 - zone);
}

/** Standard-mapping gamepad → demand: left stick up pushes (axis 1 is down-positive), right
 *  stick x twists; the D-pad (buttons 12–15) works like the arrow keys. */
export function gamepadDemand(axes: readonly number[], pressed: readonly boolean[]): Demand {
  const pad = (i: number) => (pressed[i] ? 1 : 0);
  return {
    push: clamp(-deadZone(axes[1] ?? 0) + pad(12) - pad(13)),
    twist: clamp(deadZone(axes[2] ?? 0) + pad(15) - pad(14)),
  };
}

/** Several sources at once: summed, each axis clamped to −1..1. */
export function combine(...demands: Demand[]): Demand {
  return {
    push: clamp(demands.reduce((s, d) => s + d.push, 0)),
    twist: clamp(demands.reduce((s, d) => s + d.twist, 0)),
  };
}

function clamp(v: number): number {
  return Math.max(-1, Math.min(1, v));
}

/** How often a held speed is repeated (ms): well inside the server's control timeout (250 ms
 *  by default), after which a held speed that was not repeated lapses to zero. */
export const HOLD_REPEAT_MS = 100;

/** Turns successive demands into the commands to send: an insertion speed when the push
 *  changed, a twist rate when the twist changed, nothing when neither did. Speeds are sent in
 *  hold mode: the server stops the device unless they are repeated (`repeat`), so a closed tab
 *  or a lost network never leaves a device running. */
export class DriveCommands {
  private last: Demand = { push: 0, twist: 0 };

  constructor(
    private readonly pushMmS = PUSH_MM_S,
    private readonly twistDegS = TWIST_DEG_S,
  ) {}

  private push(demand: number): Command {
    return create(CommandSchema, {
      kind: {
        case: "insertion",
        value: { mode: { case: "velocityMmS", value: demand * this.pushMmS }, hold: true },
      },
    });
  }

  private twist(demand: number): Command {
    return create(CommandSchema, {
      kind: { case: "twist", value: { mode: { case: "rateDegS", value: demand * this.twistDegS }, hold: true } },
    });
  }

  next(demand: Demand): Command[] {
    const out: Command[] = [];
    if (demand.push !== this.last.push) out.push(this.push(demand.push));
    if (demand.twist !== this.last.twist) out.push(this.twist(demand.twist));
    this.last = { ...demand };
    return out;
  }

  /** The non-zero speeds in force, to repeat every `HOLD_REPEAT_MS` while they are held. */
  repeat(): Command[] {
    const out: Command[] = [];
    if (this.last.push !== 0) out.push(this.push(this.last.push));
    if (this.last.twist !== 0) out.push(this.twist(this.last.twist));
    return out;
  }

  /** Forgets what was sent (after a reconnect the server may have stopped the device). */
  reset(): void {
    this.last = { push: 0, twist: 0 };
  }
}
