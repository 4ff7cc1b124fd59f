//! The stack panel's lines: each instrument's inserted length, its tip against the one around
//! it ("microwire 24 mm out of the microcatheter") and what its hand feels.
import { type InstrumentState, PushLimit } from "./gen/cathlab/v1/simulator_pb.js";

/** One row of the stack panel, outermost instrument first. */
export interface StackLine {
  name: string;
  /** Inserted length beyond the entry point, e.g. "312 mm" ("−4 mm": inside the one around it). */
  inserted: string;
  /** Its tip against the tip of the instrument around it; "at the entry" for the outermost. */
  relative: string;
  /** The hand's axial force, e.g. "0.12 N", with the push limit in force when one is. */
  force: string;
}

/** Millimetres with a true minus sign, whole above 10 mm and to 0.1 mm below. */
export function mm(value: number): string {
  const a = Math.abs(value);
  const text = a >= 10 ? a.toFixed(0) : a.toFixed(1);
  return `${value < 0 && Number(text) !== 0 ? "−" : ""}${text} mm`;
}

/** A short name for a relative phrase: the catalogue's kind word when the name carries one
 *  ("Microcatheter 0.017\" 150 cm" → "microcatheter"), else the name as it is. */
export function shortName(name: string): string {
  const lower = name.toLowerCase();
  for (const kind of ["microcatheter", "microwire", "guidewire", "guide catheter", "catheter", "sheath", "wire"]) {
    if (lower.includes(kind)) return kind;
  }
  return name;
}

/** How far `tipBeyondMm` puts an instrument's tip against the one around it, in words. */
export function relative(inner: string, outer: string, tipBeyondMm: number): string {
  const a = shortName(inner);
  const b = shortName(outer);
  if (Math.abs(tipBeyondMm) < 0.5) return `${a} tip level with the ${b} tip`;
  return tipBeyondMm > 0
    ? `${a} ${mm(tipBeyondMm)} out of the ${b}`
    : `${a} ${mm(-tipBeyondMm)} inside the ${b}`;
}

/** The panel's rows for `instruments` (outermost first). */
export function stackLines(instruments: readonly InstrumentState[]): StackLine[] {
  return instruments.map((it, i) => {
    const limit =
      it.pushLimit === PushLimit.FORCE ? " · force limit" : it.pushLimit === PushLimit.LENGTH ? " · at its hub" : "";
    return {
      name: it.name,
      inserted: mm(it.insertedMm),
      relative: i === 0 ? (it.insertedMm > 0 ? "in from the entry" : "at the entry") : relative(it.name, instruments[i - 1].name, it.beyondOuterMm),
      force: `${it.axialForceN.toFixed(2)} N${limit}`,
    };
  });
}
