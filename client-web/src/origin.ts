//! Which server a page may talk to, and the secrets a link carries: the decisions without the
//! browser (tested in origin.test.ts; api.ts applies them).
//!
//! The rule: a page's API base is its own origin. A `?server=` naming another origin is used
//! only when the page's own server lists that origin as one of its fleet's servers
//! (`GET /fleet-origins` → `{"origins": ["http://host:port", …]}`); any other is refused and
//! nothing is sent to it. Credentials this browser keeps (the account token, the instructor
//! key, a session token saved by the page) therefore only ever go to this origin or a listed one.
//!
//! Secrets in a link (`account`, `token`, `key`) are taken out of the address at once: the
//! address bar, the history entry, bookmarks and Referer headers never keep them.

/** The origin (`scheme://host[:port]`, the default port dropped) of an http(s) URL; undefined
 *  for anything else (another scheme, a relative or malformed URL, user:password@). */
export function httpOrigin(url: string): string | undefined {
  let parsed: URL;
  try {
    parsed = new URL(url);
  } catch {
    return undefined;
  }
  if (parsed.protocol !== "http:" && parsed.protocol !== "https:") return undefined;
  if (parsed.username || parsed.password || !parsed.hostname) return undefined;
  return parsed.origin;
}

/** The origins in a `/fleet-origins` answer (`{"origins": [...]}`), normalized; anything not an
 *  http(s) URL is left out, and an answer of another shape lists none. */
export function parseAllowList(body: unknown): string[] {
  if (typeof body !== "object" || body === null) return [];
  const origins = (body as { origins?: unknown }).origins;
  if (!Array.isArray(origins)) return [];
  const out = new Set<string>();
  for (const o of origins) {
    const origin = typeof o === "string" ? httpOrigin(o) : undefined;
    if (origin) out.add(origin);
  }
  return [...out];
}

/** Whether `target` is this page's origin or on the allow-list: where stored credentials may go. */
export function mayUse(pageOrigin: string, target: string, allowed: readonly string[]): boolean {
  const origin = httpOrigin(target);
  if (!origin) return false;
  return origin === httpOrigin(pageOrigin) || allowed.includes(origin);
}

/** Where a page's calls go. */
export type ServerDecision =
  /** This page's own origin (no `?server=`, or one naming this origin). */
  | { kind: "this"; origin: string }
  /** Another origin the page's server lists as one of its fleet. */
  | { kind: "listed"; origin: string }
  /** A `?server=` that is not used: nothing is sent to it. */
  | { kind: "refused"; requested: string; reason: "not an http(s) origin" | "not listed" };

/** Whether deciding on `requested` needs the allow-list (it names another http(s) origin). */
export function needsAllowList(pageOrigin: string, requested: string | null): boolean {
  if (!requested) return false;
  const origin = httpOrigin(requested);
  return origin !== undefined && origin !== httpOrigin(pageOrigin);
}

/** The server for a page at `pageOrigin` whose link says `?server=requested`, given the origins
 *  its own server lists. */
export function chooseServer(pageOrigin: string, requested: string | null, allowed: readonly string[]): ServerDecision {
  const own = httpOrigin(pageOrigin) ?? pageOrigin;
  if (!requested) return { kind: "this", origin: own };
  const origin = httpOrigin(requested);
  if (!origin) return { kind: "refused", requested, reason: "not an http(s) origin" };
  if (origin === own) return { kind: "this", origin };
  if (allowed.includes(origin)) return { kind: "listed", origin };
  return { kind: "refused", requested, reason: "not listed" };
}

/** The query parameters that carry secrets. */
export const SECRET_PARAMS = ["account", "token", "key"] as const;
export type SecretParam = (typeof SECRET_PARAMS)[number];

/** `href` without its secret parameters (every copy of each), and the secrets (the first of
 *  each; an empty value counts as none). `changed`: whether the address must be replaced. */
export function takeSecrets(href: string): {
  clean: string;
  secrets: Partial<Record<SecretParam, string>>;
  changed: boolean;
} {
  const url = new URL(href);
  const secrets: Partial<Record<SecretParam, string>> = {};
  let changed = false;
  for (const name of SECRET_PARAMS) {
    if (!url.searchParams.has(name)) continue;
    const value = url.searchParams.get(name);
    if (value) secrets[name] = value;
    url.searchParams.delete(name);
    changed = true;
  }
  return { clean: url.toString(), secrets, changed };
}

/** What to do with an account token a link brought, given the one this browser keeps. */
export type AccountOffer =
  /** No token in the link. */
  | { kind: "none" }
  /** The link's token is the one already kept: nothing changes. */
  | { kind: "same" }
  /** Ask first: `replaces` whether a kept account would be replaced. */
  | { kind: "ask"; token: string; replaces: boolean };

export function accountOffer(linked: string | undefined, stored: string | null): AccountOffer {
  if (!linked) return { kind: "none" };
  if (linked === stored) return { kind: "same" };
  return { kind: "ask", token: linked, replaces: !!stored };
}

/** A session a tab saved (sessionStorage), with the origin of the server its token is for. */
export interface SavedSession {
  origin: string;
  id: string;
  token: string;
  readOnly: boolean;
}

/** A saved session read back, if well formed and for `origin` (a token is only ever sent back
 *  to the server that gave it); `id`, when given, must match too. */
export function savedSessionFor(text: string | null, origin: string, id?: string | null): SavedSession | undefined {
  if (!text) return undefined;
  let saved: unknown;
  try {
    saved = JSON.parse(text);
  } catch {
    return undefined;
  }
  if (typeof saved !== "object" || saved === null) return undefined;
  const s = saved as Record<string, unknown>;
  if (typeof s.origin !== "string" || typeof s.id !== "string" || typeof s.token !== "string") return undefined;
  if (!s.id || !s.token || s.origin !== origin) return undefined;
  if (id && s.id !== id) return undefined;
  return { origin: s.origin, id: s.id, token: s.token, readOnly: s.readOnly === true };
}
