//! The instructor dashboard: every live session with a live thumbnail and metrics, a link to
//! open it read-only, and its event timeline.
import { Code, ConnectError } from "@connectrpc/connect";
import { type SimulatorClient, serverUrl, simulatorClient } from "./api.js";
import { type Event, type Metrics, type SessionInfo, SessionStatus } from "./gen/cathlab/v1/simulator_pb.js";
import { showFrames } from "./frames.js";
import { metricRows } from "./hud.js";
import { Backoff, keepOpen } from "./reconnect.js";

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
const params = new URLSearchParams(location.search);
const base = serverUrl(location);
const KEY = "cathlab.instructor.key";
const POLL_MS = 1000;

/** One session's card and its streams. */
interface Card {
  element: HTMLElement;
  stop: AbortController;
}

const cards = new Map<string, Card>();
let selected = "";
let instructorKey = params.get("key") ?? localStorage.getItem(KEY) ?? "";

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
    ...events.map((e) => {
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

function addCard(client: SimulatorClient, info: SessionInfo): Card {
  const element = document.createElement("article");
  element.className = "card";
  element.dataset.session = info.sessionId;
  const title = document.createElement("h3");
  title.textContent = `${info.label || "session"} · ${info.sceneName}`;
  const image = document.createElement("img");
  image.alt = `X-ray of session ${info.sessionId}`;
  const actions = document.createElement("div");
  actions.className = "actions";
  const open = document.createElement("a");
  open.textContent = "Open read-only";
  open.target = "_blank";
  open.href = `/?${new URLSearchParams({ session: info.sessionId, token: instructorKey, role: "observer" })}`;
  const timeline = document.createElement("button");
  timeline.textContent = "Timeline";
  timeline.addEventListener("click", () => select(client, info.sessionId));
  actions.append(open, timeline);
  element.append(title, image, document.createElement("dl"), actions);
  $("sessions").append(element);
  const card: Card = { element, stop: new AbortController() };
  void showFrames(client, info.sessionId, image, { size: 192, quality: 70, signal: card.stop.signal });
  return card;
}

function showStatus(status: string, detail = "") {
  const el = $("connection");
  el.dataset.status = status;
  el.textContent = status;
  el.title = detail;
}

async function poll(signal: AbortSignal) {
  const client = simulatorClient(base, instructorKey);
  const backoff = new Backoff(500, 5000);
  while (!signal.aborted) {
    let wait = POLL_MS;
    try {
      const { sessions } = await client.listSessions({ includeRecorded: false }, { signal });
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
        const card = cards.get(info.sessionId) ?? addCard(client, info);
        cards.set(info.sessionId, card);
        renderMetrics(card.element, info.metrics);
      }
      $("count").textContent = `(${cards.size})`;
      if (!cards.has(selected)) select(client, cards.keys().next().value ?? "");
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
$<HTMLInputElement>("key").value = instructorKey;
$("key-form").addEventListener("submit", (e) => {
  e.preventDefault();
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
void poll(polling.signal);
