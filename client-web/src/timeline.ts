//! The instructor's timeline of a session: newest first, each fluoroscopy on/off pair folded
//! into one line with its duration (a trainee taps the pedal hundreds of times).
import type { Event } from "./gen/cathlab/v1/simulator_pb.js";

/** One line of the timeline. */
export interface TimelineRow {
  /** Simulated time the line stands at (s): the event's, or a fluoroscopy run's start. */
  timeS: number;
  kind: string;
  message: string;
}

/** Events (oldest first, as the server streams them) → rows, newest first. A fluoroscopy
 *  run becomes "fluoroscopy 2.4 s" (or "fluoroscopy on" while it lasts). */
export function timelineRows(events: readonly Pick<Event, "timeS" | "kind" | "message">[]): TimelineRow[] {
  const rows: TimelineRow[] = [];
  let onAt: number | undefined;
  for (const e of events) {
    if (e.kind === "imaging" && e.message === "fluoroscopy on") {
      onAt = e.timeS;
    } else if (e.kind === "imaging" && e.message === "fluoroscopy off") {
      const start = onAt ?? e.timeS;
      rows.push({ timeS: start, kind: "imaging", message: `fluoroscopy ${(e.timeS - start).toFixed(1)} s` });
      onAt = undefined;
    } else {
      rows.push({ timeS: e.timeS, kind: e.kind, message: e.message });
    }
  }
  if (onAt !== undefined) rows.push({ timeS: onAt, kind: "imaging", message: "fluoroscopy on" });
  // Newest first; a stable sort keeps same-time events in the order they happened, reversed.
  return rows.map((r, i) => ({ r, i })).sort((a, b) => b.r.timeS - a.r.timeS || b.i - a.i).map(({ r }) => r);
}
