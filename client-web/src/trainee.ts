//! The trainee view: the live X-ray image, the controls and the HUD of one session.
import { type MessageInitShape, create } from "@bufbuild/protobuf";
import { Code, ConnectError } from "@connectrpc/connect";
import {
  type SimulatorClient,
  type TrustedServer,
  pageServer,
  showRefused,
  simulatorClient,
  takeSecretsFromAddress,
} from "./api.js";
import {
  DriveCommands,
  HOLD_REPEAT_MS,
  type Hands,
  IDLE,
  combine,
  driveKey,
  gamepadHands,
  isDriveKey,
  keyboardHands,
} from "./controls.js";
import {
  type Command,
  CommandSchema,
  type DeviceState,
  ImagingMode,
  type ListScenesResponse,
  type Metrics,
  PulseRate,
  ThrombectomyAction,
  type SceneSummary,
} from "./gen/cathlab/v1/simulator_pb.js";
import { showFrames } from "./frames.js";
import { doseLine, hudLines, reperfusionRows } from "./hud.js";
import { drawMarker } from "./marker.js";
import { shortName, stackLines } from "./stack.js";
import { type ConnectionStatus, keepOpen } from "./reconnect.js";
import { accountOffer, savedSessionFor } from "./origin.js";

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
// A link's secrets leave the address before anything else: the session token (kept in this
// tab's storage for reloads) and an account token (kept only once the trainee accepts it).
const linked = takeSecretsFromAddress();
const params = new URLSearchParams(location.search);
/** This tab's session: `{origin, id, token, readOnly}`, its token only for that origin. */
const STORAGE = "cathlab.trainee.session";
/** The trainee's account token, kept in this browser (accepted from a sign-in link). */
const ACCOUNT = "cathlab.account.token";
/** The server: this page's origin, or a `?server=` its server lists (set by main first). */
let base: TrustedServer;
/** The `?server=` this page's own links carry on (none for this page's origin). */
let serverParam: string | null = null;
let accountToken = "";

interface Joined {
  id: string;
  token: string;
  readOnly: boolean;
}

/** The session to show: from the URL, from this tab's last session, or a new one. */
async function join(): Promise<Joined> {
  const id = params.get("session");
  const token = linked.token;
  if (id && token) return remember({ id, token, readOnly: params.get("role") === "observer" });
  // This tab's last session, on this server only (its token is for the server that gave it).
  const saved = savedSessionFor(sessionStorage.getItem(STORAGE), base);
  if (saved) {
    try {
      await simulatorClient(base, saved.token).getSession({ sessionId: saved.id });
      return remember({ id: saved.id, token: saved.token, readOnly: saved.readOnly });
    } catch {
      sessionStorage.removeItem(STORAGE);
    }
  }
  // With an account token the session is the trainee's (their history, their reports).
  const creator = simulatorClient(base, accountToken || undefined);
  const { scenes, defaultScene } = await creator.listScenes({});
  const scene = params.get("scene") ?? (defaultScene || scenes[0]?.name);
  if (!scene) throw new Error("the server lists no scenes");
  const created = await creator.createSession({
    scene: { case: "sceneName", value: scene },
    label: params.get("label") ?? "trainee",
    assessment: params.get("assessment") === "1",
  });
  return remember({ id: created.sessionId, token: created.controllerToken, readOnly: false });
}

/** Keeps the session for reloads: its id in the URL, its token in this tab's storage (never
 *  in the URL). */
function remember(joined: Joined): Joined {
  sessionStorage.setItem(
    STORAGE,
    JSON.stringify({ origin: base, id: joined.id, token: joined.token, readOnly: joined.readOnly }),
  );
  const url = new URL(location.href);
  url.searchParams.set("session", joined.id);
  history.replaceState(null, "", url);
  return joined;
}

/** The account this page uses: the one kept in this browser, or the sign-in link's once the
 *  trainee accepts it here (a link alone never changes the account: a link from someone else
 *  would otherwise sign this browser into their account, and the trainee's sessions with it). */
async function settleAccount(): Promise<string> {
  const stored = localStorage.getItem(ACCOUNT) ?? "";
  const offer = accountOffer(linked.account, stored);
  if (offer.kind !== "ask") return stored;
  const box = $("account-offer");
  const name = (token: string, el: HTMLElement) =>
    simulatorClient(base, token)
      .whoAmI({})
      .then((me) => {
        el.textContent = `${me.name} (${me.role})`;
      })
      .catch(() => {
        el.textContent = "an account this server does not recognise";
      });
  $("account-offer-new").textContent = "the account in this link";
  void name(offer.token, $("account-offer-new"));
  const replaces = $("account-offer-replaces");
  if (offer.replaces) {
    replaces.textContent = "This replaces the account signed in in this browser: ";
    const current = document.createElement("strong");
    current.id = "account-offer-current";
    current.textContent = "the current account";
    replaces.append(current, ".");
    void name(stored, current);
  } else {
    replaces.textContent = "No account is signed in in this browser yet. Accept only a link you were given for yourself.";
  }
  box.hidden = false;
  $("account-ignore").focus();
  return new Promise((resolve) => {
    $("account-accept").addEventListener("click", () => {
      localStorage.setItem(ACCOUNT, offer.token);
      box.hidden = true;
      resolve(offer.token);
    });
    $("account-ignore").addEventListener("click", () => {
      box.hidden = true;
      resolve(stored);
    });
  });
}

function showStatus(status: ConnectionStatus, detail?: string) {
  const el = $("connection");
  el.dataset.status = status;
  el.textContent = status;
  el.title = detail ?? "";
}

/** A line under the image: a warning or error by default, a success styled as one. */
function say(text: string, kind: "warning" | "success" = "warning") {
  const el = $("message");
  el.textContent = text;
  el.dataset.kind = kind;
}

/** The report of the session the trainee finished here, once finished. */
let finishedReport = "";

/** "Session finished", with the link to its report. */
function showFinished() {
  const el = $("message");
  el.dataset.kind = "success";
  el.textContent = "Session finished. ";
  const a = document.createElement("a");
  a.id = "report-link";
  a.href = finishedReport;
  a.textContent = "Open the report";
  el.append(a);
}

/** The session is over: the message, with a way on. */
function sessionEnded() {
  if (finishedReport) {
    showFinished();
    for (const c of document.querySelectorAll<HTMLButtonElement | HTMLInputElement | HTMLSelectElement>(
      "#controls button, #controls input, #controls select",
    )) {
      c.disabled = true;
    }
    return;
  }
  const el = $("message");
  el.dataset.kind = "warning";
  el.textContent = "This session has ended (the server restarted or the session was closed). ";
  const fresh = document.createElement("a");
  fresh.href = `${location.pathname}${serverParam ? `?server=${encodeURIComponent(serverParam)}` : ""}`;
  fresh.textContent = "Start a new session";
  fresh.id = "new-session";
  el.append(fresh);
  for (const c of document.querySelectorAll<HTMLButtonElement | HTMLInputElement | HTMLSelectElement>(
    "#controls button, #controls input, #controls select",
  )) {
    c.disabled = true;
  }
}

function describe(e: unknown): string {
  if (e instanceof ConnectError) return `${Code[e.code]}: ${e.rawMessage}`;
  return e instanceof Error ? e.message : String(e);
}

async function main() {
  const server = await pageServer(location);
  if (!server.ok) {
    const status = $("connection");
    status.dataset.status = "refused";
    status.textContent = "not connected";
    showRefused($("message"), server);
    for (const c of document.querySelectorAll<HTMLButtonElement | HTMLInputElement | HTMLSelectElement>(
      "#controls button, #controls input, #controls select",
    )) {
      c.disabled = true;
    }
    return;
  }
  base = server.base;
  serverParam = server.param;
  accountToken = await settleAccount();
  let joined: Joined;
  try {
    joined = await join();
  } catch (e) {
    showStatus("reconnecting", describe(e));
    say(`Cannot start a session: ${describe(e)}`);
    return;
  }
  const client = simulatorClient(base, joined.token);
  document.body.dataset.session = joined.id;
  $("role").textContent = joined.readOnly ? "observer (read-only)" : "";
  if (accountToken) {
    simulatorClient(base, accountToken)
      .whoAmI({})
      .then((me) => {
        $("account").textContent = `${me.name} (${me.role})`;
      })
      .catch(() => {
        $("account").textContent = "account token not recognised";
      });
  }
  const info = await client.getSession({ sessionId: joined.id });
  const listed = await client.listScenes({});
  const scene = listed.scenes.find((s) => s.name === info.sceneName);
  $("scene").textContent = `${info.label || "session"} · ${info.sceneName}`;
  const device = $<HTMLSelectElement>("device");
  for (const [i, name] of (scene?.devices ?? []).entries()) device.add(new Option(name, String(i)));
  device.value = String(info.activeDevice);
  // A coaxial scene: two hands, the stack panel and the exchange instead of the device list.
  const stacked = (scene?.stack.length ?? 0) >= 2;
  if (stacked) setUpStack(scene!, listed);
  $("device-choice").hidden = stacked || device.options.length < 2;
  const target = scene?.target ?? "";
  // Guidance the session allows (an assessment turns it off; an older server sends none).
  const guidance = info.guidance ?? { targetMarker: true, targetDistance: true, prompts: true };
  document.body.dataset.guidance = guidance.prompts ? "on" : "off";
  if (!guidance.prompts) $("prompt").hidden = true;
  if (!guidance.targetDistance) $("hud-target-title").textContent = "Target";

  let state: DeviceState | undefined;
  let metrics: Metrics | undefined;
  const stop = new AbortController();
  window.addEventListener("pagehide", () => stop.abort());

  // The HUD, redrawn at most every 50 ms (a timer, not an animation frame: an observer's
  // page in the background keeps its figures current).
  let hudPending = false;
  const redraw = () => {
    if (hudPending) return;
    hudPending = true;
    setTimeout(() => {
      hudPending = false;
      const lines = hudLines(state, metrics, target, guidance.targetDistance);
      $("hud-inserted").textContent = lines.inserted;
      $("hud-twist").textContent = lines.twist;
      $("hud-fluoro").textContent = lines.fluoroscopy;
      $("hud-contrast").textContent = lines.contrast;
      $("hud-force").textContent = lines.wallForce;
      $("hud-force-box").classList.toggle("warning", lines.warning);
      $("hud-target").textContent = lines.target;
      $("hud-target").classList.toggle("success", lines.reached);
      if (stacked && state) showStack(state);
    }, 50);
  };

  void keepOpen(
    async (received, signal) => {
      for await (const s of client.streamState({ sessionId: joined.id, tipOnly: true }, { signal })) {
        state = s;
        received();
        redraw();
      }
    },
    (status, detail) => {
      showStatus(status, detail);
      if (status === "ended") {
        // The server is back but no longer has the session (it restarted, or the session was
        // closed): say so, stop, and offer a new one.
        stop.abort();
        sessionStorage.removeItem(STORAGE);
        sessionEnded();
      }
    },
    stop.signal,
    undefined,
    undefined,
    (e) => e instanceof ConnectError && (e.code === Code.NotFound || e.code === Code.Unauthenticated),
  );
  // Metrics by a 1 Hz poll, not a stream: over plain HTTP/1.1 a browser holds at most six
  // connections to a server, and the two streams here (state, frames) are enough.
  void (async () => {
    let resets = 0;
    let reached = false;
    while (!stop.signal.aborted) {
      try {
        const now = await client.getSession({ sessionId: joined.id }, { signal: stop.signal });
        metrics = now.metrics;
        const clot = metrics?.thrombectomy;
        $("thrombectomy").hidden = clot === undefined;
        if (clot) document.body.dataset.clot = "";
        else delete document.body.dataset.clot;
        if (clot) $("aspiration").setAttribute("aria-pressed", String(clot.aspiration));
        const procedure = Object.fromEntries(reperfusionRows(metrics));
        $("hud-etici-box").hidden = procedure.eTICI === undefined;
        $("hud-etici").textContent = procedure.eTICI ?? "—";
        $("hud-passes-box").hidden = procedure.Passes === undefined;
        $("hud-passes").textContent = procedure.Passes ?? "—";
        if (metrics?.targetReached) $("demonstrate").setAttribute("aria-pressed", "false");
        if (metrics && metrics.divergenceResets > resets) {
          say("The simulation diverged and the device was put back at its start.");
        }
        if (metrics?.targetReached && !reached && guidance.prompts) say(`Target ${target} reached.`, "success");
        resets = metrics?.divergenceResets ?? 0;
        reached = metrics?.targetReached ?? false;
        redraw();
      } catch {
        // The state stream reports the connection.
      }
      await new Promise((r) => setTimeout(r, 1000));
    }
  })();
  void showFrames(client, joined.id, $<HTMLImageElement>("xray"), {
    size: 512,
    quality: 85,
    signal: stop.signal,
    shown: (frame) => {
      const mode =
        frame.mode === ImagingMode.SUBTRACTION ? "DSA" : frame.mode === ImagingMode.ROADMAP ? "ROADMAP" : "FLUORO";
      $("mode").textContent = frame.held ? `${mode} · last image hold` : mode;
      $("frame-info").textContent = `frame ${frame.index} · t ${frame.timeS.toFixed(2)} s`;
      $("dose").textContent = doseLine(frame);
      $("prompt").hidden = true;
      drawMarker($<HTMLElement>("target-marker") as unknown as SVGSVGElement, frame, target);
      // The imaging buttons follow the server's mode (after a reload, or a refused command).
      $("dsa").setAttribute("aria-pressed", String(frame.mode === ImagingMode.SUBTRACTION));
      $("roadmap").setAttribute("aria-pressed", String(frame.mode === ImagingMode.ROADMAP));
      const message = $("message");
      if (frame.mode === ImagingMode.ROADMAP && /roadmap/i.test(message.textContent ?? "")) say("");
    },
  });

  if (joined.readOnly) {
    for (const el of $("controls").querySelectorAll<HTMLButtonElement | HTMLInputElement | HTMLSelectElement>(
      "button, input, select",
    )) {
      el.disabled = true;
    }
    return;
  }
  controls(client, joined.id, stacked ? scene!.stack.length : 1);
  $("finish").addEventListener("click", async () => {
    try {
      await client.closeSession({ sessionId: joined.id });
    } catch (e) {
      say(`Cannot finish: ${describe(e)}`);
      return;
    }
    sessionStorage.removeItem(STORAGE);
    const report = new URL("report.html", location.href);
    report.search = "";
    if (serverParam) report.searchParams.set("server", serverParam);
    report.searchParams.set("session", joined.id);
    report.searchParams.set("token", joined.token);
    finishedReport = report.toString();
    sessionEnded();
  });
}

/** Fills the hands' instrument names, the exchange lists and shows the stack panel. */
function setUpStack(scene: SceneSummary, listed: ListScenesResponse) {
  const n = scene.stack.length;
  document.body.dataset.stacked = "true";
  $("left-hand").hidden = false;
  $("right-title").textContent = "Right hand";
  $("right-instrument").textContent = scene.stack[n - 1].device;
  fillHands(scene.stack.map((s) => s.device));
  $("stack-panel").hidden = false;
  $("exchange").hidden = false;
  const bring = $<HTMLSelectElement>("exchange-device");
  for (const [i, spare] of scene.spares.entries()) bring.add(new Option(`back table: ${spare}`, `spare:${i}`));
  for (const d of listed.catalogue) bring.add(new Option(`${d.name}`, `catalogue:${d.id}`));
}

/** The left hand's and the exchange's instrument lists for a stack of these instruments
 *  (outermost first): the left hand holds the one just outside the innermost (the catheter
 *  over the wire; a parked guide is there to be chosen), the exchange offers the innermost. */
function fillHands(names: readonly string[]) {
  const n = names.length;
  const left = $<HTMLSelectElement>("left-instrument");
  const which = $<HTMLSelectElement>("exchange-instrument");
  left.replaceChildren();
  which.replaceChildren();
  for (let i = 0; i < n - 1; i++) left.add(new Option(names[i], String(i)));
  for (let i = 1; i < n; i++) which.add(new Option(names[i], String(i)));
  left.value = String(Math.max(n - 2, 0));
  which.value = String(n - 1);
}

/** The stack panel and the hands' instrument names from a state. */
function showStack(state: DeviceState) {
  const list = $("stack");
  const lines = stackLines(state.instruments);
  while (list.children.length > lines.length) list.lastElementChild!.remove();
  while (list.children.length < lines.length) {
    const li = document.createElement("li");
    for (const part of ["name", "inserted", "relative", "force"]) {
      const span = document.createElement("span");
      span.className = part;
      li.append(span, part === "name" ? "" : " ");
    }
    list.append(li);
  }
  for (const [i, line] of lines.entries()) {
    const li = list.children[i] as HTMLElement;
    li.dataset.instrument = String(i);
    li.querySelector(".name")!.textContent = line.name;
    (li.querySelector(".name") as HTMLElement).title = line.name;
    li.querySelector(".inserted")!.textContent = line.inserted;
    li.querySelector(".relative")!.textContent = `· ${line.relative}`;
    li.querySelector(".force")!.textContent = `· ${line.force}`;
  }
  // A device loaded or taken out: the hands' lists follow, the left hand regrips the one
  // just outside the new innermost (the right hand always drives the innermost).
  const leftSelect = $<HTMLSelectElement>("left-instrument");
  if (state.instruments.length >= 2 && leftSelect.options.length !== state.instruments.length - 1) {
    fillHands(state.instruments.map((it) => it.name));
    leftSelect.dispatchEvent(new Event("change"));
  }
  // After an exchange the names change: keep the hands' and the exchange's labels true.
  const names = state.instruments.map((it) => shortName(it.name));
  const rename = (select: HTMLSelectElement) => {
    for (const o of select.options) {
      const name = state.instruments[Number(o.value)]?.name;
      if (name && o.text !== name) o.text = name;
    }
  };
  rename($<HTMLSelectElement>("left-instrument"));
  rename($<HTMLSelectElement>("exchange-instrument"));
  const innermost = state.instruments.at(-1)?.name;
  if (innermost) $("right-instrument").textContent = innermost;
  document.body.dataset.instruments = names.join(",");
}

/** Wires the keyboard, buttons, gamepad and forms to commands; `instruments` is the stack's
 *  size (1 for a one-device scene, whose device both hands drive). */
function controls(client: SimulatorClient, sessionId: string, instruments: number) {
  let seq = 0n;
  /** Sends one command; says why when the server refuses it. Resolves to whether it applied. */
  const sendNow = async (command: Command): Promise<boolean> => {
    seq += 1n;
    try {
      await client.sendCommand({ sessionId, seq, command });
      return true;
    } catch (e) {
      if (e instanceof ConnectError && e.code === Code.PermissionDenied) say("This view is read-only.");
      else if (e instanceof ConnectError && e.code === Code.FailedPrecondition) say(e.rawMessage);
      else say(`Command failed: ${describe(e)}`);
      return false;
    }
  };
  // One at a time, in order: concurrent calls can arrive out of order, and a held speed's
  // repeat landing after the stop that followed it would set the instrument moving again.
  let queue: Promise<unknown> = Promise.resolve();
  const send = (command: Command): Promise<boolean> => {
    const sent = queue.then(() => sendNow(command));
    queue = sent;
    return sent;
  };
  const command = (kind: MessageInitShape<typeof CommandSchema>["kind"]) => send(create(CommandSchema, { kind }));

  // Push/pull and twist per hand: keys and on-screen buttons held, plus the gamepad. With one
  // instrument both hands drive it (no instrument named: the server's default).
  const stacked = instruments >= 2;
  const held = new Set<string>();
  const leftSelect = $<HTMLSelectElement>("left-instrument");
  const left = new DriveCommands(stacked ? Number(leftSelect.value) : undefined);
  // The right hand drives the innermost, whatever the stack holds now (no instrument named:
  // the server's innermost, after a load or an unload too).
  const right = new DriveCommands(undefined);
  let pad: Hands = { left: IDLE, right: IDLE };
  const update = () => {
    const keys = keyboardHands(held);
    const l = combine(keys.left, pad.left);
    const r = combine(keys.right, pad.right);
    if (stacked) {
      for (const c of [...left.next(l), ...right.next(r)]) void send(c);
    } else {
      for (const c of right.next(combine(l, r))) void send(c);
    }
  };
  leftSelect.addEventListener("change", () => {
    for (const c of left.regrip(Number(leftSelect.value))) void send(c);
    update();
  });
  // Held speeds are repeated while held: the server lets a held speed lapse when it stops
  // hearing it (a closed tab, a lost network, a sleeping laptop).
  setInterval(() => {
    for (const c of [...left.repeat(), ...right.repeat()]) void send(c);
  }, HOLD_REPEAT_MS);
  const HOLD_KEYS: Record<string, Record<string, string>> = {
    right: { push: "ArrowUp", pull: "ArrowDown", ccw: "ArrowLeft", cw: "ArrowRight" },
    left: { push: "w", pull: "s", ccw: "a", cw: "d" },
  };
  let pedal = false;
  const setPedal = (down: boolean) => {
    if (down === pedal) return;
    pedal = down;
    $("pedal").classList.toggle("held", down);
    void command({ case: "fluoroscopy", value: down });
  };
  // The drive keys drive the instruments wherever focus is: listened to in the capture phase
  // and kept from the focused control (an arrow on a focused slider would turn the C-arm).
  window.addEventListener(
    "keydown",
    (e) => {
      if (!isDriveKey(e.key) || e.ctrlKey || e.metaKey || e.altKey) return;
      e.preventDefault();
      e.stopPropagation();
      const key = driveKey(e.key);
      if (key === "f") {
        setPedal(true);
      } else if (!held.has(key)) {
        held.add(key);
        update();
      }
    },
    { capture: true },
  );
  window.addEventListener(
    "keyup",
    (e) => {
      if (!isDriveKey(e.key)) return;
      e.preventDefault();
      e.stopPropagation();
      const key = driveKey(e.key);
      if (key === "f") setPedal(false);
      else if (held.delete(key)) update();
    },
    { capture: true },
  );
  // Losing focus lets go of everything: a device must never run on unattended.
  window.addEventListener("blur", () => {
    held.clear();
    update();
    setPedal(false);
  });
  for (const button of document.querySelectorAll<HTMLButtonElement>("button[data-hold]")) {
    const what = button.dataset.hold!;
    const key = HOLD_KEYS[button.dataset.hand ?? "right"]?.[what];
    const down = (e: PointerEvent) => {
      e.preventDefault();
      button.setPointerCapture(e.pointerId);
      button.classList.add("held");
      if (what === "pedal") setPedal(true);
      else if (key) {
        held.add(key);
        update();
      }
    };
    const up = () => {
      button.classList.remove("held");
      if (what === "pedal") setPedal(false);
      else if (key && held.delete(key)) update();
    };
    button.addEventListener("pointerdown", down);
    button.addEventListener("pointerup", up);
    button.addEventListener("pointercancel", up);
    button.addEventListener("lostpointercapture", up);
  }
  let padPedal = false;
  const same = (a: Hands, b: Hands) =>
    a.left.push === b.left.push && a.left.twist === b.left.twist && a.right.push === b.right.push && a.right.twist === b.right.twist;
  const pollGamepad = () => {
    const gamepad = navigator.getGamepads?.().find((g) => g?.connected);
    const next = gamepad ? gamepadHands(gamepad.axes, gamepad.buttons.map((b) => b.pressed)) : { left: IDLE, right: IDLE };
    if (!same(next, pad)) {
      pad = next;
      update();
    }
    const a = gamepad?.buttons[0]?.pressed ?? false;
    if (a !== padPedal) {
      padPedal = a;
      setPedal(a);
    }
    requestAnimationFrame(pollGamepad);
  };
  requestAnimationFrame(pollGamepad);

  $("exchange-go").addEventListener("click", async () => {
    const instrument = Number($<HTMLSelectElement>("exchange-instrument").value);
    const [kind, value] = $<HTMLSelectElement>("exchange-device").value.split(/:(.*)/s);
    const device =
      kind === "spare" ? { case: "spare" as const, value: Number(value) } : { case: "catalogueId" as const, value };
    const incoming = $<HTMLSelectElement>("exchange-device").selectedOptions[0]?.text ?? "";
    const outgoing = $<HTMLSelectElement>("exchange-instrument").selectedOptions[0]?.text ?? "";
    // The server draws the instrument back to the hub first (the stack panel follows it),
    // then puts the new one there; a push on it meanwhile cancels the exchange.
    if (await command({ case: "exchange", value: { instrument, device } })) {
      say(`Exchange: withdrawing ${outgoing} to the hub, then ${incoming} goes in.`, "success");
    }
  });
  $("load-go").addEventListener("click", async () => {
    const [kind, value] = $<HTMLSelectElement>("exchange-device").value.split(/:(.*)/s);
    const device =
      kind === "spare" ? { case: "spare" as const, value: Number(value) } : { case: "catalogueId" as const, value };
    const incoming = $<HTMLSelectElement>("exchange-device").selectedOptions[0]?.text ?? "";
    if (await command({ case: "load", value: { device } })) {
      say(`Loaded: ${incoming}, its tip at the innermost's hub; push it in.`, "success");
    }
  });
  $("unload-go").addEventListener("click", async () => {
    if (await command({ case: "unload", value: {} })) {
      say("Taking the innermost out: it comes back to the hub, then off the table.", "success");
    }
  });
  $<HTMLSelectElement>("device").addEventListener("change", (e) =>
    command({ case: "selectDevice", value: Number((e.target as HTMLSelectElement).value) }),
  );
  $("reset").addEventListener("click", () => command({ case: "reset", value: true }));

  $<HTMLSelectElement>("pulse").addEventListener("change", (e) =>
    command({ case: "pulseRate", value: Number((e.target as HTMLSelectElement).value) as PulseRate }),
  );
  $("deploy-stent").addEventListener("click", async () => {
    if (await command({ case: "thrombectomy", value: ThrombectomyAction.DEPLOY_STENT })) {
      say("Deploying: the microcatheter comes back over the held stent.", "success");
    }
  });
  $("retrieve-stent").addEventListener("click", async () => {
    if (await command({ case: "thrombectomy", value: ThrombectomyAction.RETRIEVE_STENT })) {
      say("Retrieving: stent and microcatheter come back together.", "success");
    }
  });
  const demonstrate = $("demonstrate");
  demonstrate.addEventListener("click", async () => {
    const on = demonstrate.getAttribute("aria-pressed") !== "true";
    if (await command({ case: "demonstrate", value: on })) {
      demonstrate.setAttribute("aria-pressed", String(on));
      if (on) say("Demonstration: the scene's operator drives to the target; push or twist to take over.", "success");
    }
  });
  const aspiration = $("aspiration");
  aspiration.addEventListener("click", async () => {
    const on = aspiration.getAttribute("aria-pressed") !== "true";
    if (await command({ case: "aspiration", value: on })) aspiration.setAttribute("aria-pressed", String(on));
  });
  const dsa = $("dsa");
  dsa.addEventListener("click", () => {
    const on = dsa.getAttribute("aria-pressed") !== "true";
    dsa.setAttribute("aria-pressed", String(on));
    void command({ case: "dsa", value: on });
  });
  const roadmap = $("roadmap");
  roadmap.addEventListener("click", async () => {
    const on = roadmap.getAttribute("aria-pressed") !== "true";
    if (await command({ case: "roadmap", value: on })) roadmap.setAttribute("aria-pressed", String(on));
  });
  $("inject").addEventListener("click", () => {
    const volumeMl = Number($<HTMLInputElement>("volume").value);
    const rateMlS = Number($<HTMLInputElement>("rate").value);
    void command({ case: "inject", value: { volumeMl, rateMlS } });
  });
  const primary = $<HTMLInputElement>("primary");
  const secondary = $<HTMLInputElement>("secondary");
  const angle = (v: number, plus: string, minus: string) => (v === 0 ? "0°" : `${v > 0 ? plus : minus} ${Math.abs(v)}°`);
  const carm = () => {
    $("primary-out").textContent = angle(Number(primary.value), "LAO", "RAO");
    $("secondary-out").textContent = angle(Number(secondary.value), "CRA", "CAU");
    void command({ case: "carm", value: { primaryDeg: Number(primary.value), secondaryDeg: Number(secondary.value) } });
  };
  primary.addEventListener("change", carm);
  secondary.addEventListener("change", carm);
  $<HTMLSelectElement>("zoom").addEventListener("change", (e) => {
    $("stage").style.transform = `scale(${(e.target as HTMLSelectElement).value})`;
  });
}

void main();
