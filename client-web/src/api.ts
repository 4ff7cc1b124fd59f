//! The gRPC-Web connection to cathlab-server: one Simulator client per token, only ever to a
//! server this page may trust with a credential (its own origin, or one its server lists as
//! one of its fleet: see origin.ts).
import { type Client, type Interceptor, createClient } from "@connectrpc/connect";
import { createGrpcWebTransport } from "@connectrpc/connect-web";
import { Simulator } from "./gen/cathlab/v1/simulator_pb.js";
import { type SecretParam, chooseServer, httpOrigin, needsAllowList, parseAllowList, takeSecrets } from "./origin.js";

export type SimulatorClient = Client<typeof Simulator>;

/** The base URL of a server this page may send credentials to: made only here, by
 *  [`pageServer`] and [`AllowList.trust`]. */
export type TrustedServer = string & { readonly __trusted: unique symbol };

/** Every origin handed out as trusted; [`simulatorClient`] refuses any other. */
const trusted = new Set<string>();
function trust(origin: string): TrustedServer {
  trusted.add(origin);
  return origin as TrustedServer;
}

/** Where the page's server publishes its fleet's origins (same origin, no credentials). */
export const ALLOW_LIST_PATH = "/fleet-origins";

/** The origins this page's server lists as its fleet's (none when it publishes no list). */
export async function fetchAllowList(): Promise<string[]> {
  try {
    const answer = await fetch(ALLOW_LIST_PATH, {
      credentials: "omit",
      cache: "no-store",
      redirect: "error",
      headers: { accept: "application/json" },
    });
    if (!answer.ok) return [];
    return parseAllowList(await answer.json());
  } catch {
    return [];
  }
}

/** The servers other than this page's own that may be trusted: the allow-list, fetched when
 *  first needed and again (at most every 5 s) when asked about an origin not on it (a server
 *  that joined the fleet since). */
export class AllowList {
  private origins: string[] = [];
  private fetchedAt = Number.NEGATIVE_INFINITY;
  private pending: Promise<string[]> | undefined;

  constructor(private readonly pageOrigin: string) {}

  private async refresh(): Promise<string[]> {
    if (Date.now() - this.fetchedAt < 5000) return this.origins;
    this.pending ??= fetchAllowList().then((origins) => {
      this.origins = origins;
      this.fetchedAt = Date.now();
      this.pending = undefined;
      return origins;
    });
    return this.pending;
  }

  /** `address` as a trusted server, or undefined when it is neither this page's origin nor listed. */
  async trust(address: string): Promise<TrustedServer | undefined> {
    const origin = httpOrigin(address);
    if (!origin) return undefined;
    if (origin === httpOrigin(this.pageOrigin)) return trust(origin);
    if (!this.origins.includes(origin)) await this.refresh();
    return this.origins.includes(origin) ? trust(origin) : undefined;
  }
}

/** The server a page talks to. */
export type PageServer =
  /** `base`: where calls go; `param`: the `?server=` value the page's own links carry on
   *  (null for this page's origin). */
  | { ok: true; base: TrustedServer; param: string | null }
  /** `?server=` named a server this page will not use: nothing was sent to it. */
  | { ok: false; requested: string; message: string };

/** This page's server: its own origin, or the `?server=` of its address when that is this
 *  origin or one its server lists (only then is the allow-list fetched, from this origin). */
export async function pageServer(location: Location, allowList = new AllowList(location.origin)): Promise<PageServer> {
  const requested = new URLSearchParams(location.search).get("server");
  const listed = needsAllowList(location.origin, requested) ? await fetchListed(allowList, requested!) : [];
  const decision = chooseServer(location.origin, requested, listed);
  if (decision.kind === "refused") {
    return {
      ok: false,
      requested: decision.requested,
      message:
        decision.reason === "not listed"
          ? `This link asks this page to connect to ${decision.requested}, which this server (${location.origin}) does not list as one of its servers. Nothing was sent there: your account token and instructor key stay in this browser.`
          : `This link names a server this page cannot use (${decision.requested}). Nothing was sent there.`,
    };
  }
  return { ok: true, base: trust(decision.origin), param: decision.kind === "this" ? null : decision.origin };
}

async function fetchListed(allowList: AllowList, requested: string): Promise<string[]> {
  const origin = httpOrigin(requested)!;
  return (await allowList.trust(origin)) ? [origin] : [];
}

/** The address without its secrets (`account`, `token`, `key`): replaced in the address bar
 *  and the history entry at once, before the page makes any request. The secrets are kept in
 *  memory only; what the page does with them is its own choice. */
export function takeSecretsFromAddress(): Partial<Record<SecretParam, string>> {
  const { clean, secrets, changed } = takeSecrets(location.href);
  if (changed) history.replaceState(history.state, "", clean);
  return secrets;
}

/** The same page on this server without `?server=`: where a refused link's user can go instead. */
export function thisServersPage(location: Location): string {
  const url = new URL(location.href);
  url.searchParams.delete("server");
  return url.toString();
}

/** A client whose every call carries `authorization: Bearer <token>`, for a trusted server only. */
export function simulatorClient(baseUrl: TrustedServer, token?: string): SimulatorClient {
  if (!trusted.has(baseUrl)) throw new Error(`not a server this page may use: ${baseUrl}`);
  const bearer: Interceptor = (next) => async (request) => {
    if (token) request.header.set("authorization", `Bearer ${token}`);
    return next(request);
  };
  return createClient(
    Simulator,
    createGrpcWebTransport({ baseUrl, interceptors: [bearer], useBinaryFormat: true }),
  );
}

/** Says on the page that the link's server was refused, with a link to this server's page. */
export function showRefused(el: HTMLElement, server: { requested: string; message: string }) {
  el.hidden = false;
  el.textContent = `${server.message} `;
  const here = document.createElement("a");
  here.id = "this-server";
  here.href = thisServersPage(location);
  here.textContent = `Open this page on ${location.origin} instead`;
  el.append(here);
  document.body.dataset.server = "refused";
}
