//! The trainee view: the live X-ray image, the controls and the HUD of one session.
import { type MessageInitShape, create } from "@bufbuild/protobuf";
import { Code, ConnectError } from "@connectrpc/connect";
import { type SimulatorClient, serverUrl, simulatorClient } from "./api.js";
import { DriveCommands, HOLD_REPEAT_MS, combine, gamepadDemand, isDriveKey, keyboardDemand } from "./controls.js";
import {
  type Command,
  CommandSchema,
  type DeviceState,
  ImagingMode,
  type Metrics,
  PulseRate,
} from "./gen/cathlab/v1/simulator_pb.js";
import { showFrames } from "./frames.js";
import { doseLine, hudLines } from "./hud.js";
import { drawMarker } from "./marker.js";
import { type ConnectionStatus, keepOpen } from "./reconnect.js";

const $ = <T extends HTMLElement>(id: string) => document.getElementById(id) as T;
const params = new URLSearchParams(location.search);
const base = serverUrl(location);
const STORAGE = "cathlab.trainee.session";

interface Joined {
  id: string;
  token: string;
  readOnly: boolean;
}

/** The session to show: from the URL, from this tab's last session, or a new one. */
async function join(): Promise<Joined> {
  const id = params.get("session");
  const token = params.get("token");
  if (id && token) return { id, token, readOnly: params.get("role") === "observer" };
  const saved = sessionStorage.getItem(STORAGE);
  if (saved) {
    const { id, token } = JSON.parse(saved) as { id: string; token: string };
    try {
      await simulatorClient(base, token).getSession({ sessionId: id });
      return remember({ id, token, readOnly: false });
    } catch {
      sessionStorage.removeItem(STORAGE);
    }
  }
  const anonymous = simulatorClient(base);
  const { scenes } = await anonymous.listScenes({});
  const scene = params.get("scene") ?? scenes[0]?.name;
  if (!scene) throw new Error("the server lists no scenes");
  const created = await anonymous.createSession({
    scene: { case: "sceneName", value: scene },
    label: params.get("label") ?? "trainee",
    assessment: params.get("assessment") === "1",
  });
  return remember({ id: created.sessionId, token: created.controllerToken, readOnly: false });
}

function remember(joined: Joined): Joined {
  sessionStorage.setItem(STORAGE, JSON.stringify({ id: joined.id, token: joined.token }));
  const url = new URL(location.href);
  url.searchParams.set("session", joined.id);
  url.searchParams.set("token", joined.token);
  history.replaceState(null, "", url);
  return joined;
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

/** The session is over: the message, with a way on. */
function sessionEnded() {
  const el = $("message");
  el.dataset.kind = "warning";
  el.textContent = "This session has ended (the server restarted or the session was closed). ";
  const fresh = document.createElement("a");
  fresh.href = `${location.pathname}${params.get("server") ? `?server=${encodeURIComponent(params.get("server")!)}` : ""}`;
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
  const info = await client.getSession({ sessionId: joined.id });
  const scene = (await client.listScenes({})).scenes.find((s) => s.name === info.sceneName);
  $("scene").textContent = `${info.label || "session"} · ${info.sceneName}`;
  const device = $<HTMLSelectElement>("device");
  for (const [i, name] of (scene?.devices ?? []).entries()) device.add(new Option(name, String(i)));
  device.value = String(info.activeDevice);
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
  controls(client, joined.id);
}

/** Wires the keyboard, buttons, gamepad and forms to commands. */
function controls(client: SimulatorClient, sessionId: string) {
  let seq = 0n;
  /** Sends one command; says why when the server refuses it. Resolves to whether it applied. */
  const send = async (command: Command): Promise<boolean> => {
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
  const command = (kind: MessageInitShape<typeof CommandSchema>["kind"]) => send(create(CommandSchema, { kind }));

  // Push/pull and twist: keys and on-screen buttons held, plus the gamepad.
  const held = new Set<string>();
  const drive = new DriveCommands();
  let pad = { push: 0, twist: 0 };
  const update = () => {
    for (const c of drive.next(combine(keyboardDemand(held), pad))) void send(c);
  };
  // Held speeds are repeated while held: the server lets a held speed lapse when it stops
  // hearing it (a closed tab, a lost network, a sleeping laptop).
  setInterval(() => {
    for (const c of drive.repeat()) void send(c);
  }, HOLD_REPEAT_MS);
  const HOLD_KEYS: Record<string, string> = { push: "ArrowUp", pull: "ArrowDown", ccw: "ArrowLeft", cw: "ArrowRight" };
  let pedal = false;
  const setPedal = (down: boolean) => {
    if (down === pedal) return;
    pedal = down;
    $("pedal").classList.toggle("held", down);
    void command({ case: "fluoroscopy", value: down });
  };
  // The drive keys drive the device wherever focus is: listened to in the capture phase and
  // kept from the focused control (an arrow on a focused slider would turn the C-arm).
  window.addEventListener(
    "keydown",
    (e) => {
      if (!isDriveKey(e.key)) return;
      e.preventDefault();
      e.stopPropagation();
      if (e.key === "f" || e.key === "F") {
        setPedal(true);
      } else if (!held.has(e.key)) {
        held.add(e.key);
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
      if (e.key === "f" || e.key === "F") setPedal(false);
      else if (held.delete(e.key)) update();
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
    const down = (e: PointerEvent) => {
      e.preventDefault();
      button.setPointerCapture(e.pointerId);
      button.classList.add("held");
      if (what === "pedal") setPedal(true);
      else {
        held.add(HOLD_KEYS[what]);
        update();
      }
    };
    const up = () => {
      button.classList.remove("held");
      if (what === "pedal") setPedal(false);
      else if (held.delete(HOLD_KEYS[what])) update();
    };
    button.addEventListener("pointerdown", down);
    button.addEventListener("pointerup", up);
    button.addEventListener("pointercancel", up);
    button.addEventListener("lostpointercapture", up);
  }
  let padPedal = false;
  const pollGamepad = () => {
    const gamepad = navigator.getGamepads?.().find((g) => g?.connected);
    const next = gamepad ? gamepadDemand(gamepad.axes, gamepad.buttons.map((b) => b.pressed)) : { push: 0, twist: 0 };
    if (next.push !== pad.push || next.twist !== pad.twist) {
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

  $<HTMLSelectElement>("device").addEventListener("change", (e) =>
    command({ case: "selectDevice", value: Number((e.target as HTMLSelectElement).value) }),
  );
  $("reset").addEventListener("click", () => command({ case: "reset", value: true }));
  $<HTMLSelectElement>("pulse").addEventListener("change", (e) =>
    command({ case: "pulseRate", value: Number((e.target as HTMLSelectElement).value) as PulseRate }),
  );
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
