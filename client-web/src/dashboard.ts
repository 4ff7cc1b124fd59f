//! The instructor dashboard: every live session with a live thumbnail and metrics, a link to
//! open it read-only (with the session's observer token: the instructor key never goes into a
//! URL), its event timeline, and the recorded sessions (closed, or interrupted by a restart).
import { Code, ConnectError } from "@connectrpc/connect";
import {
  AllowList,
  type SimulatorClient,
  type TrustedServer,
  pageServer,
  showRefused,
  simulatorClient,
  takeSecretsFromAddress,
} from "./api.js";
import { type Event, type Metrics, type SessionInfo, SessionStatus } from "./gen/cathlab/v1/simulator_pb.js";
import { showFrames } from "./frames.js";
import { metricRows } from "./hud.js";
import { Backoff, keepOpen } from "./reconnect.js";
import { timelineRows } from "./timeline.js";
import { httpOrigin } from "./origin.js";

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
// A link's secrets leave the address before anything else. The key lives in the page's
// storage, never in its URL: an old link's `?key=` only fills the form (Connect uses and
// keeps it), so a link cannot swap the key this browser uses.
const linked = takeSecretsFromAddress();
/** The server: this page's origin, or a `?server=` its server lists (set before any call). */
let base: TrustedServer | undefined;
/** The `?server=` this page's own links carry on (none for this page's origin). */
let serverParam: string | null = null;
/** The fleet's servers this page's server lists: the only others the key is sent to. */
const allowList = new AllowList(location.origin);
const KEY = "cathlab.instructor.key";
const POLL_MS = 1000;

/** One session's card and its streams. */
interface Card {
  element: HTMLElement;
  stop: AbortController;
  /** The client of the server that runs the session (another server of the fleet, or this
   *  one); none for a server this page's server does not list (nothing is sent there). */
  client: SimulatorClient | undefined;
}

const cards = new Map<string, Card>();
let accountsShown = false;
let selected = "";
let instructorKey = localStorage.getItem(KEY) ?? "";

/** "label · scene · started 14:02" (local time), so that two sessions can be told apart. */
function sessionTitle(info: SessionInfo): string {
  const started = new Date(info.createdUnixS * 1000);
  const at = `${String(started.getHours()).padStart(2, "0")}:${String(started.getMinutes()).padStart(2, "0")}`;
  return `${info.label || "session"} · ${info.sceneName} · started ${at} · ${info.sessionId.slice(0, 8)}`;
}

function describe(e: unknown): string {
  if (e instanceof ConnectError) return `${Code[e.code]}: ${e.rawMessage}`;
  return e instanceof Error ? e.message : String(e);
}

function renderMetrics(element: HTMLElement, m: Metrics | undefined) {
  const dl = element.querySelector("dl")!;
  dl.replaceChildren(
    ...metricRows(m).flatMap(([k, v]) => {
      const dt = document.createElement("dt");
      dt.textContent = k;
      const dd = document.createElement("dd");
      dd.textContent = v;
      return [dt, dd];
    }),
  );
}

function renderTimeline(events: Event[]) {
  $("timeline-session").textContent = selected ? selected.slice(0, 8) : "(choose a session)";
  $("timeline").replaceChildren(
    ...timelineRows(events).map((e) => {
      const li = document.createElement("li");
      li.className = e.kind;
      const time = document.createElement("time");
      time.textContent = `${e.timeS.toFixed(2)} s`;
      const kind = document.createElement("span");
      kind.className = "kind";
      kind.textContent = e.kind.replace("_", " ");
      li.append(time, kind, e.message);
      return li;
    }),
  );
}

/** Shows one session's timeline: its event stream (which starts with every event so far)
 *  runs only while it is selected, so the dashboard holds one stream per thumbnail plus one.
 *  Over plain HTTP/1.1 a browser opens at most six connections to a server. */
let timelineStop = new AbortController();
function select(client: SimulatorClient, id: string) {
  if (id === selected) return;
  selected = id;
  timelineStop.abort();
  timelineStop = new AbortController();
  for (const [cardId, card] of cards) card.element.classList.toggle("selected", cardId === id);
  renderTimeline([]);
  if (!id) return;
  let events: Event[] = [];
  void keepOpen(
    async (received, signal) => {
      events = [];
      for await (const update of client.streamMetrics({ sessionId: id }, { signal })) {
        received();
        if (update.kind.case === "event") {
          events.push(update.kind.value);
          renderTimeline(events);
        }
      }
    },
    () => {},
    timelineStop.signal,
  );
}

/**
 * Over plain HTTP/1.1 a browser opens at most six connections to a server, and each stream
 * holds one for as long as it lasts: thumbnails stream for at most three cards, leaving room
 * for the timeline stream and the page's own calls (with more, the page's buttons would wait
 * forever). Over TLS browsers speak HTTP/2, which multiplexes: every card streams.
 */
const MAX_THUMBNAIL_STREAMS = location.protocol === "https:" ? Number.POSITIVE_INFINITY : 3;
let thumbnailStreams = 0;

function addCard(client: SimulatorClient | undefined, info: SessionInfo): Card {
  const element = document.createElement("article");
  element.className = "card";
  element.dataset.session = info.sessionId;
  const title = document.createElement("h3");
  title.textContent = sessionTitle(info);
  const image = document.createElement("img");
  image.alt = `X-ray of session ${info.sessionId}`;
  const actions = document.createElement("div");
  actions.className = "actions";
  const open = document.createElement("a");
  open.textContent = "Open read-only";
  open.target = "_blank";
  open.href = `/?${new URLSearchParams({
    ...(serverParam ? { server: serverParam } : {}),
    session: info.sessionId,
    token: info.observerToken,
    role: "observer",
  })}`;
  const timeline = document.createElement("button");
  timeline.textContent = "Timeline";
  if (client) timeline.addEventListener("click", () => select(client, info.sessionId));
  else timeline.disabled = true;
  const where: HTMLElement[] = [];
  if (info.serverAddress) {
    // Another server of the fleet runs it: its streams come from there (with the instructor
    // key, when this page's server lists it); its observer token stays on that server, so
    // the read-only page is opened there.
    const there = httpOrigin(info.serverAddress);
    if (there) open.href = new URL(`/dashboard.html`, there).toString();
    else open.removeAttribute("href");
    open.textContent = "Its server";
    const address = document.createElement("p");
    address.className = "muted server-address";
    address.textContent = client
      ? `on ${info.serverAddress}`
      : `on ${info.serverAddress}, which this server does not list among its fleet's servers: not contacted (the instructor key is not sent there)`;
    where.push(address);
  }
  actions.append(open, timeline);
  element.append(title, ...where, image, document.createElement("dl"), actions);
  $("sessions").append(element);
  const card: Card = { element, stop: new AbortController(), client };
  if (!client) {
    image.hidden = true;
  } else if (thumbnailStreams < MAX_THUMBNAIL_STREAMS) {
    thumbnailStreams += 1;
    card.stop.signal.addEventListener("abort", () => {
      thumbnailStreams -= 1;
    });
    void showFrames(client, info.sessionId, image, { size: 192, quality: 70, signal: card.stop.signal });
  } else {
    image.hidden = true;
    const note = document.createElement("p");
    note.className = "muted thumbnail-off";
    note.textContent = `No thumbnail: over plain HTTP this page streams at most ${MAX_THUMBNAIL_STREAMS} (serve over TLS for all).`;
    image.after(note);
  }
  return card;
}

/** A link to a session's report (the report page finds the instructor key in this browser). */
function reportLink(sessionId: string): HTMLAnchorElement {
  const a = document.createElement("a");
  const url = new URL("report.html", location.href);
  url.search = "";
  if (serverParam) url.searchParams.set("server", serverParam);
  url.searchParams.set("session", sessionId);
  a.href = url.toString();
  a.className = "report-link";
  a.textContent = "report";
  return a;
}

/** Trainee and instructor accounts: each with a sign-in link and, opened, their sessions and scores. */
async function renderAccounts(client: SimulatorClient) {
  const { accounts } = await client.listAccounts({});
  $("accounts").replaceChildren(
    ...accounts.map((a) => {
      const li = document.createElement("li");
      li.dataset.account = a.accountId;
      const details = document.createElement("details");
      const summary = document.createElement("summary");
      summary.textContent = `${a.name} (${a.role})`;
      const list = document.createElement("ol");
      details.append(summary, list);
      details.addEventListener("toggle", async () => {
        if (!details.open) return;
        try {
          const { entries } = await client.getHistory({ accountId: a.accountId });
          list.replaceChildren(
            ...entries.map((e) => {
              const item = document.createElement("li");
              const scores = e.assessed
                ? `${e.within} of ${e.judged} within expert range; time ${(e.metrics.procedure_time_s ?? 0).toFixed(1)} s, fluoro ${(e.metrics.fluoroscopy_time_s ?? 0).toFixed(1)} s, errors ${e.metrics.errors ?? 0}`
                : "not assessed yet";
              item.textContent = `${new Date(e.createdUnixS * 1000).toLocaleString()} ${e.sceneName}: ${scores} `;
              item.append(reportLink(e.sessionId));
              return item;
            }),
          );
          if (!entries.length) list.textContent = "No sessions yet.";
        } catch (err) {
          list.textContent = `Cannot list the sessions: ${describe(err)}`;
        }
      });
      li.append(details);
      return li;
    }),
  );
}

/** The recorded sessions, newest first: closed ones and those a server restart interrupted. */
function renderRecorded(recorded: SessionInfo[]) {
  const sorted = [...recorded].sort((a, b) => b.createdUnixS - a.createdUnixS);
  $("recorded-count").textContent = `(${sorted.length})`;
  $("recorded").replaceChildren(
    ...sorted.map((info) => {
      const li = document.createElement("li");
      li.dataset.session = info.sessionId;
      const status =
        info.status === SessionStatus.INTERRUPTED ? "interrupted" : info.status === SessionStatus.LOST ? "lost" : "closed";
      li.className = status;
      const rows = Object.fromEntries(metricRows(info.metrics));
      li.textContent = `${sessionTitle(info)} — ${status}; ${info.commands} commands; time ${rows.Time}, fluoro ${rows.Fluoro}, target ${rows.Target} `;
      li.append(reportLink(info.sessionId));
      return li;
    }),
  );
}

function showStatus(status: string, detail = "") {
  const el = $("connection");
  el.dataset.status = status;
  el.textContent = status;
  el.title = detail;
}

async function poll(signal: AbortSignal) {
  if (!base) return;
  const client = simulatorClient(base, instructorKey);
  const backoff = new Backoff(500, 5000);
  while (!signal.aborted) {
    let wait = POLL_MS;
    try {
      const { sessions } = await client.listSessions({ includeRecorded: true }, { signal });
      showStatus("connected");
      $("message").textContent = "";
      backoff.reset();
      const live = sessions.filter((s) => s.status === SessionStatus.RUNNING);
      const ids = new Set(live.map((s) => s.sessionId));
      for (const [id, card] of cards) {
        if (!ids.has(id)) {
          card.stop.abort();
          card.element.remove();
          cards.delete(id);
        }
      }
      for (const info of live) {
        let card = cards.get(info.sessionId);
        if (!card || (!card.client && info.serverAddress)) {
          // A session another server of the fleet runs: the key goes there only when this
          // page's server lists that server (ListSessions' addresses come from the fleet's
          // registry; the allow-list is read again, at most every 5 s, while one is not on it).
          const there = info.serverAddress ? await allowList.trust(info.serverAddress) : base;
          if (signal.aborted) return;
          if (card && there) {
            // Listed since: the card again, with its streams.
            card.stop.abort();
            card.element.remove();
            card = undefined;
          }
          card ??= addCard(there ? simulatorClient(there, instructorKey) : undefined, info);
        }
        cards.set(info.sessionId, card);
        renderMetrics(card.element, info.metrics);
      }
      $("count").textContent = `(${cards.size})`;
      if (!accountsShown) {
        accountsShown = true;
        void renderAccounts(client).catch(() => {
          accountsShown = false;
        });
      }
      renderRecorded(sessions.filter((s) => s.status !== SessionStatus.RUNNING));
      if (!cards.get(selected)?.client) {
        const first = [...cards.entries()].find(([, card]) => card.client);
        select(first?.[1].client ?? client, first?.[0] ?? "");
      }
    } catch (e) {
      if (signal.aborted) return;
      if (e instanceof ConnectError && (e.code === Code.Unauthenticated || e.code === Code.PermissionDenied)) {
        showStatus("connecting", "instructor key needed");
        $("message").textContent = "Enter the instructor key (CATHLAB_INSTRUCTOR_KEY on the server).";
        return;
      }
      showStatus("reconnecting", describe(e));
      $("message").textContent = `Server unreachable: ${describe(e)}`;
      wait = backoff.next();
    }
    await new Promise((r) => setTimeout(r, wait));
  }
}

let polling = new AbortController();
$<HTMLInputElement>("key").value = linked.key ?? instructorKey;
$("key-form").addEventListener("submit", (e) => {
  e.preventDefault();
  if (!base) return;
  instructorKey = $<HTMLInputElement>("key").value;
  localStorage.setItem(KEY, instructorKey);
  polling.abort();
  for (const card of cards.values()) {
    card.stop.abort();
    card.element.remove();
  }
  cards.clear();
  selected = "";
  timelineStop.abort();
  polling = new AbortController();
  void poll(polling.signal);
});

/** The server first (nothing is sent before it is known to be trusted), then the poll. */
async function start() {
  const server = await pageServer(location);
  if (!server.ok) {
    const status = $("connection");
    status.dataset.status = "refused";
    status.textContent = "not connected";
    showRefused($("message"), server);
    for (const c of document.querySelectorAll<HTMLButtonElement | HTMLInputElement | HTMLSelectElement>(
      "form button, form input, form select",
    )) {
      c.disabled = true;
    }
    return;
  }
  base = server.base;
  serverParam = server.param;
  if (linked.key && linked.key !== instructorKey) {
    // Not used until the instructor says so.
    showStatus("connecting", "instructor key needed");
    $("message").textContent =
      "This link carried an instructor key: it was taken out of the address and is not used or kept until you press Connect.";
  } else {
    void poll(polling.signal);
  }
  void fillScenes(base);
}
void start();

// A session started here for a trainee: guided, or an assessment without guidance. The
// trainee gets the controller link; the instructor watches it like any other.
async function fillScenes(base: TrustedServer) {
  try {
    const { scenes, defaultScene } = await simulatorClient(base).listScenes({});
    const select = $<HTMLSelectElement>("new-scene");
    for (const s of scenes) select.add(new Option(`${s.name} — ${s.description}`, s.name));
    if (defaultScene) select.value = defaultScene;
  } catch {
    // The poll reports an unreachable server.
  }
}
$("new-account").addEventListener("submit", async (e) => {
  e.preventDefault();
  if (!base) return;
  const out = $("account-link");
  const client = simulatorClient(base, instructorKey);
  try {
    const account = await client.createAccount({
      name: $<HTMLInputElement>("account-name").value,
      role: $<HTMLSelectElement>("account-role").value,
    });
    const url = new URL("index.html", location.href);
    url.search = "";
    if (serverParam) url.searchParams.set("server", serverParam);
    // The trainee's page asks before it signs their browser in with it.
    url.searchParams.set("account", account.token);
    out.textContent = `${account.name}'s sign-in link (shown once; it carries their token): `;
    const a = document.createElement("a");
    a.href = url.toString();
    a.textContent = url.toString();
    a.id = "account-url";
    out.append(a);
    await renderAccounts(client);
  } catch (err) {
    out.textContent = `Cannot create the account: ${describe(err)}`;
  }
});
$("new-session").addEventListener("submit", async (e) => {
  e.preventDefault();
  if (!base) return;
  const link = $("new-link");
  try {
    const assessment = $<HTMLInputElement>("new-assessment").checked;
    const created = await simulatorClient(base).createSession({
      scene: { case: "sceneName", value: $<HTMLSelectElement>("new-scene").value },
      label: $<HTMLInputElement>("new-label").value,
      assessment,
    });
    const url = new URL("index.html", location.href);
    url.search = "";
    if (serverParam) url.searchParams.set("server", serverParam);
    url.searchParams.set("session", created.sessionId);
    url.searchParams.set("token", created.controllerToken);
    link.textContent = `${assessment ? "Assessment" : "Guided"} session started. The trainee's link: `;
    const a = document.createElement("a");
    a.href = url.toString();
    a.textContent = url.toString();
    a.id = "trainee-link";
    link.append(a);
  } catch (err) {
    link.textContent = `Cannot start the session: ${describe(err)}`;
  }
});
