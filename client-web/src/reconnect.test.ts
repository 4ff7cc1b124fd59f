import { describe, expect, it } from "vitest";
import { Backoff, type ConnectionStatus, keepOpen } from "./reconnect.js";

describe("back-off", () => {
  it("doubles from the first delay up to the cap, with ±20 % jitter, and restarts on reset", () => {
    const middle = new Backoff(250, 5000, () => 0.5);
    expect([1, 2, 3, 4, 5, 6, 7].map(() => middle.next())).toEqual([250, 500, 1000, 2000, 4000, 5000, 5000]);
    middle.reset();
    expect(middle.next()).toBe(250);
    expect(new Backoff(1000, 5000, () => 0).next()).toBe(800);
    expect(new Backoff(1000, 5000, () => 0.999999).next()).toBe(1200);
  });
});

describe("keepOpen", () => {
  it("reports connected on the first message and reconnects after errors and ends", async () => {
    const statuses: string[] = [];
    const sleeps: number[] = [];
    const stop = new AbortController();
    let calls = 0;
    await keepOpen(
      async (received) => {
        calls += 1;
        if (calls === 1) throw new Error("refused");
        if (calls === 2) throw new Error("refused again");
        if (calls === 3) {
          received();
          received();
          return; // the server ended the stream
        }
        stop.abort();
      },
      (s: ConnectionStatus, detail?: string) => statuses.push(detail ? `${s}: ${detail}` : s),
      stop.signal,
      new Backoff(100, 1000, () => 0.5),
      async (ms) => {
        sleeps.push(ms);
      },
    );
    expect(calls).toBe(4);
    expect(statuses).toEqual([
      "connecting",
      "reconnecting: refused",
      "reconnecting",
      "reconnecting: refused again",
      "reconnecting",
      "connected",
      "reconnecting: stream ended",
      "reconnecting",
    ]);
    // Two failures back off 100 then 200 ms; a message resets the back-off to 100 ms.
    expect(sleeps).toEqual([100, 200, 100]);
  });
  it("ends without retrying when the error is final (the session is gone)", async () => {
    const statuses: string[] = [];
    let calls = 0;
    await keepOpen(
      async () => {
        calls += 1;
        if (calls === 1) throw new Error("refused");
        throw new Error("not found");
      },
      (s: ConnectionStatus, detail?: string) => statuses.push(detail ? `${s}: ${detail}` : s),
      new AbortController().signal,
      new Backoff(100, 1000, () => 0.5),
      async () => {},
      (e) => e instanceof Error && e.message === "not found",
    );
    expect(calls).toBe(2);
    expect(statuses).toEqual(["connecting", "reconnecting: refused", "reconnecting", "ended: not found"]);
  });
});
