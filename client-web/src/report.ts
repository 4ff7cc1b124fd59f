//! The session report page (report.html?session=ID): scores against the scene's expert
//! benchmark, a timeline of phases, errors and events, charts, a replay scrubber (the X-ray
//! frame and the 3D device path at any moment, re-rendered by the server from the recorded
//! commands), JSON/CSV export and printing, and the trainee's learning curve on the scene.
import { Code, ConnectError } from "@connectrpc/connect";
import uPlot from "uplot";
import "uplot/dist/uPlot.min.css";
import {
  type SimulatorClient,
  type TrustedServer,
  pageServer,
  showRefused,
  simulatorClient,
  takeSecretsFromAddress,
} from "./api.js";
import { savedSessionFor } from "./origin.js";
import {
  type HistoryPoint,
  type SessionReport,
  frameAt,
  learningCurve,
  metricsCsv,
  parseReport,
  project,
  samplesCsv,
  series,
  timeline,
} from "./reportData.js";

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
// A link's secrets leave the address before anything else: the session token of the
// trainee's "Finish" link is kept in this tab's storage (for reloads), for this server only.
const linked = takeSecretsFromAddress();
const params = new URLSearchParams(location.search);
/** The server: this page's origin, or a `?server=` its server lists (set by main first). */
let base: TrustedServer;
const sessionId = params.get("session") ?? "";
/** Where the trainee page keeps an account token, and the dashboard the instructor key. */
export const ACCOUNT = "cathlab.account.token";
const KEY = "cathlab.instructor.key";
/** The session token a link brought, `{origin, id, token}` (this tab only). */
const LINKED = "cathlab.report.session";

function describe(e: unknown): string {
  if (e instanceof ConnectError) return `${Code[e.code]}: ${e.rawMessage}`;
  return e instanceof Error ? e.message : String(e);
}

function status(text: string, kind: string) {
  const el = $("connection");
  el.dataset.status = kind;
  el.textContent = text;
}

function fail(text: string) {
  status("error", "reconnecting");
  const el = $("report-error");
  el.hidden = false;
  el.textContent = text;
}

/** The credentials to try, in order: the link's token (or the one this tab kept from it, for
 *  this server and session only), this browser's account, the instructor key. Only ever sent
 *  to `base`: this page's origin or a server its server lists. */
function credentials(): string[] {
  const kept = savedSessionFor(sessionStorage.getItem(LINKED), base, sessionId)?.token;
  const out = [linked.token ?? kept, localStorage.getItem(ACCOUNT), localStorage.getItem(KEY)];
  return [...new Set(out.filter((t): t is string => !!t))];
}

function refused(e: unknown): boolean {
  return e instanceof ConnectError && (e.code === Code.PermissionDenied || e.code === Code.Unauthenticated);
}

/**
 * `call` with `first` (if given), then each of this browser's credentials, until one is let
 * in: the answer and the client that got it. A refusal tries the next; any other failure is
 * thrown at once, and when every credential is refused the last refusal is.
 */
async function withCredentials<T>(
  call: (c: SimulatorClient) => Promise<T>,
  first?: SimulatorClient,
): Promise<{ value: T; client: SimulatorClient }> {
  let last: unknown = new Error("no account token or instructor key in this browser");
  const clients = credentials().map((t) => simulatorClient(base, t));
  for (const client of first ? [first, ...clients] : clients) {
    try {
      return { value: await call(client), client };
    } catch (e) {
      if (!refused(e)) throw e;
      last = e;
    }
  }
  throw last;
}

function download(name: string, type: string, text: string) {
  const a = document.createElement("a");
  a.href = URL.createObjectURL(new Blob([text], { type }));
  a.download = name;
  document.body.append(a);
  a.click();
  a.remove();
}

function format(v: number, unit: string): string {
  if (!Number.isFinite(v)) return "—";
  if (Number.isInteger(v) && unit === "") return String(v);
  const digits = Math.abs(v) >= 100 ? 0 : Math.abs(v) >= 10 ? 1 : Math.abs(v) >= 1 ? 2 : 3;
  return `${v.toFixed(digits)}${unit ? ` ${unit}` : ""}`;
}

function chart(el: HTMLElement, labels: string[], data: number[][], opts: Partial<uPlot.Options> = {}) {
  const colours = ["#4ea1ff", "#3fb950", "#ff6b5a", "#d2a8ff", "#e3b341"];
  return new uPlot(
    {
      width: 480,
      height: 200,
      scales: { x: { time: false } },
      series: [{ label: "t (s)" }, ...labels.map((label, i) => ({ label, stroke: colours[i % colours.length], width: 1.5 }))],
      axes: [{ stroke: "#8b949e" }, { stroke: "#8b949e" }],
      ...opts,
    },
    data as uPlot.AlignedData,
    el,
  );
}

function renderScores(report: SessionReport) {
  const verdicts = new Map(report.verdicts.map((v) => [v.key, v]));
  const body = $("scores").querySelector("tbody")!;
  body.replaceChildren(
    ...report.metrics.map((m) => {
      const v = verdicts.get(m.key);
      const tr = document.createElement("tr");
      tr.dataset.key = m.key;
      const cells = [
        m.label,
        format(m.value, m.unit),
        v?.expert !== null && v?.expert !== undefined ? format(v.expert, m.unit) : "",
        v ? format(v.limit, m.unit) : "",
        v ? (v.within ? "within expert range" : "outside expert range") : "",
      ];
      for (const [i, text] of cells.entries()) {
        const td = document.createElement("td");
        td.textContent = text;
        if (i === 4 && v) td.className = v.within ? "within" : "outside";
        tr.append(td);
      }
      return tr;
    }),
  );
  const within = report.verdicts.filter((v) => v.within).length;
  $("verdict-summary").textContent = report.verdicts.length
    ? `(${within} of ${report.verdicts.length} within the expert range)`
    : "(the scene has no expert benchmark)";
}

function renderTimeline(report: SessionReport) {
  const bar = $("timeline");
  const list = $("timeline-list");
  const items = timeline(report);
  bar.replaceChildren(
    ...items.map((item) => {
      const el = document.createElement("div");
      el.className = item.kind;
      el.style.left = `${item.from * 100}%`;
      if (item.kind !== "event") el.style.width = `${Math.max(0.3, (item.to - item.from) * 100)}%`;
      el.title = item.detail;
      if (item.kind === "phase") el.textContent = item.label;
      return el;
    }),
  );
  const cursor = document.createElement("div");
  cursor.className = "cursor";
  cursor.id = "timeline-cursor";
  bar.append(cursor);
  list.replaceChildren(
    ...items
      .filter((i) => i.kind !== "event" || !/imaging|overload/.test(i.label))
      .sort((a, b) => a.from - b.from)
      .map((item) => {
        const li = document.createElement("li");
        li.className = item.kind;
        li.dataset.kind = item.kind;
        li.textContent = `${item.kind === "error" ? "Error — " : item.kind === "phase" ? "Phase — " : ""}${item.detail}`;
        return li;
      }),
  );
}

function renderCharts(report: SessionReport) {
  const s = series(report);
  const names = s.inserted.map((_, i) => `instrument ${i + 1}`);
  chart($("chart-insertion"), names, [s.time, ...s.inserted] as number[][]);
  chart($("chart-speed"), ["tip speed"], [s.time, s.speed]);
  chart($("chart-force"), ["aortic", "neck", "intracranial"], [s.time, ...s.force]);
  chart($("chart-dose"), ["fluoroscopy on", "air kerma (mGy)"], [s.time, s.fluoroscopy, s.kerma]);
}

/** The replay: a scrubber over the report's frames; each shows its X-ray and the device path. */
function renderReplay(client: SimulatorClient, report: SessionReport) {
  const scrubber = $<HTMLInputElement>("scrubber");
  const img = $<HTMLImageElement>("replay-frame");
  const canvas = $<HTMLCanvasElement>("replay-path");
  const azimuth = $<HTMLInputElement>("azimuth");
  scrubber.max = String(Math.max(0, report.frames.length - 1));
  const cache = new Map<number, string>();
  let shown = -1;
  let wanted = 0;
  const draw = (index: number) => {
    const frame = report.frames[index];
    const g = canvas.getContext("2d");
    if (!frame || !g) return;
    const az = Number(azimuth.value);
    const all = report.frames.flatMap((f) => f.instruments.flat()).map((p) => project(p, az, 0));
    const xs = all.map((p) => p[0]);
    const ys = all.map((p) => p[1]);
    const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
    const scale = (0.9 * canvas.width) / Math.max(x1 - x0, y1 - y0, 1);
    const cx = (x0 + x1) / 2;
    const cy = (y0 + y1) / 2;
    g.fillStyle = "#000";
    g.fillRect(0, 0, canvas.width, canvas.height);
    const colours = ["#8b949e", "#4ea1ff", "#3fb950", "#e3b341"];
    frame.instruments.forEach((line, i) => {
      g.strokeStyle = colours[i % colours.length];
      g.lineWidth = 2;
      g.beginPath();
      line.forEach((p, k) => {
        const [x, y] = project(p, az, 0);
        const u = canvas.width / 2 + (x - cx) * scale;
        const v = canvas.height / 2 - (y - cy) * scale;
        if (k === 0) g.moveTo(u, v);
        else g.lineTo(u, v);
      });
      g.stroke();
    });
  };
  const show = async (index: number) => {
    wanted = index;
    const frame = report.frames[index];
    if (!frame) return;
    $("replay-time").textContent = `${frame.time_s.toFixed(1)} s`;
    const cursor = document.getElementById("timeline-cursor");
    if (cursor) cursor.style.left = `${(frame.time_s / Math.max(report.duration_s, 1e-9)) * 100}%`;
    draw(index);
    let url = cache.get(index);
    if (!url) {
      try {
        const got = await client.getReportFrame({ sessionId, index });
        url = URL.createObjectURL(new Blob([got.png as Uint8Array<ArrayBuffer>], { type: "image/png" }));
        cache.set(index, url);
      } catch (e) {
        fail(`Replay frame ${index}: ${describe(e)}`);
        return;
      }
    }
    if (wanted === index && shown !== index) {
      img.src = url;
      img.dataset.index = String(index);
      shown = index;
    }
  };
  scrubber.addEventListener("input", () => void show(Number(scrubber.value)));
  azimuth.addEventListener("input", () => draw(Number(scrubber.value)));
  // Clicking the timeline jumps the replay there.
  $("timeline").addEventListener("click", (e) => {
    const box = $("timeline").getBoundingClientRect();
    const t = ((e.clientX - box.left) / box.width) * report.duration_s;
    scrubber.value = String(frameAt(report, t));
    void show(Number(scrubber.value));
  });
  void show(0);
}

async function renderCurve(client: SimulatorClient, report: SessionReport, accountId: string, scene: string) {
  const note = $("curve-note");
  if (!accountId) {
    note.textContent = "This session was not made with a trainee account: there is no history to draw.";
    return;
  }
  let history: HistoryPoint[];
  try {
    // The history needs an account or the instructor role (a session's own token is not
    // enough): the first credential of this browser that may read it.
    const got = (await withCredentials((c) => c.getHistory({ accountId }), client)).value;
    history = got.entries.map((e) => ({
      sessionId: e.sessionId,
      createdUnixS: e.createdUnixS,
      sceneName: e.sceneName,
      assessed: e.assessed,
      metrics: { ...e.metrics },
      expert: { ...e.expert },
    }));
    note.textContent = `${got.account?.name ?? "The trainee"}'s sessions on ${scene}, oldest first.`;
  } catch (e) {
    note.textContent = `No history: ${describe(e)}`;
    return;
  }
  const select = $<HTMLSelectElement>("curve-metric");
  select.replaceChildren(
    ...report.metrics.map((m) => {
      const o = document.createElement("option");
      o.value = m.key;
      o.textContent = `${m.label}${m.unit ? ` (${m.unit})` : ""}`;
      return o;
    }),
  );
  select.value = report.metrics.some((m) => m.key === "procedure_time_s") ? "procedure_time_s" : report.metrics[0]?.key;
  let plot: uPlot | undefined;
  const draw = () => {
    const points = learningCurve(history, scene, select.value);
    const el = $("chart-curve");
    el.dataset.points = String(points.length);
    plot?.destroy();
    const limit = report.verdicts.find((v) => v.key === select.value)?.limit;
    const xs = points.map((p) => p[0]);
    const data = [xs, points.map((p) => p[1])];
    if (limit !== undefined) data.push(xs.map(() => limit));
    plot = new uPlot(
      {
        width: 480,
        height: 200,
        scales: { x: { time: false } },
        series: [
          { label: "attempt" },
          { label: select.selectedOptions[0]?.textContent ?? select.value, stroke: "#4ea1ff", width: 2, points: { show: true, size: 8 } },
          ...(limit !== undefined ? [{ label: "expert limit", stroke: "#3fb950", dash: [6, 4] }] : []),
        ],
        axes: [{ stroke: "#8b949e" }, { stroke: "#8b949e" }],
      },
      data as uPlot.AlignedData,
      el,
    );
  };
  select.addEventListener("change", draw);
  draw();
  $("history").replaceChildren(
    ...history
      .filter((h) => h.sceneName === scene)
      .map((h) => {
        const li = document.createElement("li");
        const a = document.createElement("a");
        const url = new URL(location.href);
        url.searchParams.set("session", h.sessionId);
        a.href = url.toString();
        a.textContent = `${new Date(h.createdUnixS * 1000).toLocaleString()} — ${h.assessed ? `procedure ${format(h.metrics.procedure_time_s ?? NaN, "s")}` : "not assessed yet"}`;
        if (h.sessionId === sessionId) li.className = "current";
        li.dataset.session = h.sessionId;
        li.dataset.metrics = JSON.stringify(h.metrics);
        li.append(a);
        return li;
      }),
  );
}

async function main() {
  const server = await pageServer(location);
  if (!server.ok) {
    status("not connected", "refused");
    showRefused($("report-error"), server);
    return;
  }
  base = server.base;
  if (linked.token && sessionId) {
    sessionStorage.setItem(LINKED, JSON.stringify({ origin: base, id: sessionId, token: linked.token }));
  }
  if (!sessionId) {
    fail("No session: open this page as report.html?session=ID.");
    return;
  }
  status("computing the report…", "connecting");
  let got: Awaited<ReturnType<SimulatorClient["getReport"]>>;
  let client: SimulatorClient;
  try {
    ({ value: got, client } = await withCredentials((c) => c.getReport({ sessionId })));
  } catch (e) {
    if (refused(e)) $("token-form").hidden = false;
    fail(`The report of session ${sessionId} cannot be shown: ${describe(e)}`);
    return;
  }
  let report: SessionReport;
  try {
    report = parseReport(got.json);
  } catch (e) {
    fail(`The report of session ${sessionId} cannot be shown: ${describe(e)}`);
    return;
  }
  status("ready", "connected");
  $("report-body").hidden = false;
  document.body.dataset.ready = "1";
  $("title").textContent = `${got.traineeName || "Anonymous trainee"} — ${got.sceneName}`;
  $("subtitle").textContent = `${new Date(got.createdUnixS * 1000).toLocaleString()}; ${report.duration_s.toFixed(1)} s simulated; ${report.errors.length} error(s)`;
  renderScores(report);
  renderTimeline(report);
  renderCharts(report);
  renderReplay(client, report);
  $("export-json").addEventListener("click", () =>
    download(`cathlab-report-${sessionId}.json`, "application/json", got.json),
  );
  $("export-csv").addEventListener("click", () =>
    download(`cathlab-report-${sessionId}.csv`, "text/csv", metricsCsv(report)),
  );
  $("export-samples").addEventListener("click", () =>
    download(`cathlab-samples-${sessionId}.csv`, "text/csv", samplesCsv(report)),
  );
  $("print").addEventListener("click", () => window.print());
  await renderCurve(client, report, got.accountId, got.sceneName);
}

$("token-form").addEventListener("submit", (e) => {
  e.preventDefault();
  if (!base) return;
  const token = $<HTMLInputElement>("token").value.trim();
  if (token) localStorage.setItem(ACCOUNT, token);
  location.reload();
});

void main();
