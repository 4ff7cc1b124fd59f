//! Keeping a server stream open: retry with capped, jittered exponential back-off, and a
//! connection status for the page.

export type ConnectionStatus = "connecting" | "connected" | "reconnecting" | "ended";

/** Back-off delays (ms): first, doubling, capped, with ±20 % jitter from `random`. */
export class Backoff {
  private attempt = 0;

  constructor(
    private readonly firstMs = 250,
    private readonly capMs = 5000,
    private readonly random: () => number = Math.random,
  ) {}

  next(): number {
    const base = Math.min(this.capMs, this.firstMs * 2 ** this.attempt);
    this.attempt += 1;
    return Math.round(base * (0.8 + 0.4 * this.random()));
  }

  reset(): void {
    this.attempt = 0;
  }
}

/** Runs `open` (which consumes one stream and calls `received` for each message) again and
 *  again until `signal` aborts, reporting the status; the back-off restarts after any message.
 *  An error for which `final` holds (the server is back but the session is gone) ends it with
 *  the status "ended": retrying could never succeed. */
export async function keepOpen(
  open: (received: () => void, signal: AbortSignal) => Promise<void>,
  status: (s: ConnectionStatus, detail?: string) => void,
  signal: AbortSignal,
  backoff = new Backoff(),
  sleep: (ms: number) => Promise<void> = (ms) => new Promise((r) => setTimeout(r, ms)),
  final: (e: unknown) => boolean = () => false,
): Promise<void> {
  let first = true;
  while (!signal.aborted) {
    status(first ? "connecting" : "reconnecting");
    let live = false;
    try {
      await open(() => {
        if (!live) {
          live = true;
          backoff.reset();
          status("connected");
        }
      }, signal);
      if (signal.aborted) return;
      status("reconnecting", "stream ended");
    } catch (e) {
      if (signal.aborted) return;
      const detail = e instanceof Error ? e.message : String(e);
      if (final(e)) {
        status("ended", detail);
        return;
      }
      status("reconnecting", detail);
    }
    first = false;
    await sleep(backoff.next());
  }
}
