//! Trainee input: keyboard, on-screen buttons and a gamepad combined into a push/pull speed
//! (mm/s) and twist rate (deg/s) per hand, sent as commands only when they change.
//!
//! Two hands, as at the table: the left hand holds an outer instrument (the catheter hub),
//! the right hand the innermost (the wire's torquer). Keys: W/S push/pull and A/D twist the
//! left hand's instrument, the arrows the right hand's; gamepad: left stick left hand, right
//! stick (and D-pad) right hand. A one-device scene has one instrument: both hands drive it.
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

/** Both hands' demands: `left` for the outer instrument, `right` for the innermost. */
export interface Hands {
  left: Demand;
  right: Demand;
}

export const IDLE: Demand = { push: 0, twist: 0 };

/** The left hand's keys, lower case (W push, S pull, D clockwise, A counter-clockwise). */
const LEFT_KEYS = ["w", "s", "a", "d"];

/** A key as the drive keys see it: letters in lower case (Caps Lock or Shift held). */
export function driveKey(key: string): string {
  return key.length === 1 ? key.toLowerCase() : key;
}

/** The keys that drive the instruments (arrows, W A S D) and the fluoroscopy pedal (F). */
export function isDriveKey(key: string): boolean {
  const k = driveKey(key);
  return k === "ArrowUp" || k === "ArrowDown" || k === "ArrowLeft" || k === "ArrowRight" || k === "f" || LEFT_KEYS.includes(k);
}

function keyAxis(held: ReadonlySet<string>, plus: string, minus: string): number {
  return (held.has(plus) ? 1 : 0) - (held.has(minus) ? 1 : 0);
}

/** The right hand's keys held → demand: ↑ pushes, ↓ pulls, → twists clockwise, ← counter-clockwise. */
export function keyboardDemand(held: ReadonlySet<string>): Demand {
  return { push: keyAxis(held, "ArrowUp", "ArrowDown"), twist: keyAxis(held, "ArrowRight", "ArrowLeft") };
}

/** Keys held (as `driveKey` gives them) → both hands: W/S/A/D the left, the arrows the right. */
export function keyboardHands(held: ReadonlySet<string>): Hands {
  return {
    left: { push: keyAxis(held, "w", "s"), twist: keyAxis(held, "d", "a") },
    right: keyboardDemand(held),
  };
}

/** A stick axis with a dead zone, rescaled so the output starts at 0 at its edge. */
export function deadZone(value: number, zone = DEAD_ZONE): number {
  if (!Number.isFinite(value) || Math.abs(value) <= zone) return 0;
  return (Math.sign(value) * (Math.min(Math.abs(value), 1) - zone)) / (1 - zone);
}

/** Standard-mapping gamepad → both hands: each stick's y pushes (up, which is negative) and
 *  its x twists, the left stick (axes 0, 1) the left hand, the right stick (axes 2, 3) the
 *  right hand; the D-pad (buttons 12–15) works like the arrow keys. */
export function gamepadHands(axes: readonly number[], pressed: readonly boolean[]): Hands {
  const pad = (i: number) => (pressed[i] ? 1 : 0);
  return {
    left: { push: clamp(-deadZone(axes[1] ?? 0)), twist: clamp(deadZone(axes[0] ?? 0)) },
    right: {
      push: clamp(-deadZone(axes[3] ?? 0) + pad(12) - pad(13)),
      twist: clamp(deadZone(axes[2] ?? 0) + pad(15) - pad(14)),
    },
  };
}

/** Several sources at once: summed, each axis clamped to −1..1. */
export function combine(...demands: Demand[]): Demand {
  return {
    push: clamp(demands.reduce((s, d) => s + d.push, 0)),
    twist: clamp(demands.reduce((s, d) => s + d.twist, 0)),
  };
}

/** −1..1, and 0 rather than −0 (a still stick is not a negative demand). */
function clamp(v: number): number {
  return Math.max(-1, Math.min(1, v)) || 0;
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

  /** `instrument`: the stack index the commands name (none: the server's default, the
   *  innermost, which is the only one in a one-device scene). */
  constructor(
    public instrument: number | undefined = undefined,
    private readonly pushMmS = PUSH_MM_S,
    private readonly twistDegS = TWIST_DEG_S,
  ) {}

  private push(demand: number): Command {
    return create(CommandSchema, {
      instrument: this.instrument,
      kind: {
        case: "insertion",
        value: { mode: { case: "velocityMmS", value: demand * this.pushMmS }, hold: true },
      },
    });
  }

  private twist(demand: number): Command {
    return create(CommandSchema, {
      instrument: this.instrument,
      kind: { case: "twist", value: { mode: { case: "rateDegS", value: demand * this.twistDegS }, hold: true } },
    });
  }

  /** Takes the hand to another instrument: the zero speeds that stop the one it held (when
   *  it was moving), then nothing moves until the next demand. */
  regrip(instrument: number | undefined): Command[] {
    const stop = this.next(IDLE);
    this.instrument = instrument;
    return stop;
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
