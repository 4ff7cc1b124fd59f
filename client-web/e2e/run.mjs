// End-to-end tests of the web client in headless Chromium (playwright-core driving Debian's
// chromium) against a real cathlab-server serving the built client (dist/). Prints one
// `test result:` line like cargo's, saves screenshots to test-results/, exits 1 on failure.
//
//   node e2e/run.mjs [--server PATH] [--chromium PATH] [--only REGEX]
//
// The server defaults to ../target/debug/cathlab-server (built by `cargo test`). `--only`
// runs the tests whose names match (the others are skipped, not counted; most tests after
// the first rely on the ones before them, the link-safety ones do not).
import { spawn } from "node:child_process";
import { createServer } from "node:http";
import { mkdirSync, mkdtempSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, resolve } from "node:path";
import { createInterface } from "node:readline";
import { chromium } from "playwright-core";

const here = new URL("..", import.meta.url).pathname;
const repo = resolve(here, "..");
const arg = (name, fallback) => {
  const i = process.argv.indexOf(name);
  return i >= 0 ? process.argv[i + 1] : fallback;
};
const serverBinary = resolve(arg("--server", process.env.CATHLAB_SERVER ?? join(repo, "target/debug/cathlab-server")));
const chromiumPath = arg("--chromium", process.env.CHROMIUM ?? "/usr/bin/chromium");
const only = arg("--only", undefined);
const artifacts = join(here, "test-results");
mkdirSync(artifacts, { recursive: true });
const KEY = "e2e-instructor-key";

/** Starts the server on a free port; resolves with its base URL once it listens. */
function startServer(dir, listen = "127.0.0.1:0") {
  // One browser, one address: the per-client session and creation limits (attacked in the
  // server's attack tests) are lifted for the pages these tests open.
  const config = join(dir, "e2e-server.toml");
  writeFileSync(config, "max_sessions_per_client = 16\nsession_creations_per_minute = 1000\n");
  const child = spawn(
    serverBinary,
    [
      "--listen", listen,
      "--database", join(dir, "e2e.sqlite"),
      "--scenes", join(repo, "scenes"),
      "--web-root", join(here, "dist"),
      "--exit-on-stdin-eof",
      "--config", config,
      // The sessions a finished test's pages left are closed 20 s after their pages went,
      // as the server's 10-minute default would in a day's use, so that they do not load
      // the two cores for the tests after them.
      "--unattended-timeout", "20",
    ],
    { env: { ...process.env, CATHLAB_INSTRUCTOR_KEY: KEY, RUST_LOG: "warn" }, stdio: ["pipe", "pipe", "inherit"] },
  );
  return new Promise((resolvePromise, reject) => {
    const timer = setTimeout(() => reject(new Error("server did not start in 60 s")), 60_000);
    child.on("exit", (code) => reject(new Error(`server exited with ${code} before listening`)));
    createInterface({ input: child.stdout }).on("line", (line) => {
      const m = /listening on (\S+)/.exec(line);
      if (m) {
        clearTimeout(timer);
        resolvePromise({ child, url: `http://${m[1]}` });
      }
    });
  });
}

const assert = (condition, message) => {
  if (!condition) throw new Error(message);
};
const millimetres = (text) => Number.parseFloat(text);

/** A frame's pixels averaged over 8×8 blocks (quantum noise averages out, a moved wire not). */
async function blocks(page, selector) {
  return page.$eval(selector, (img) => {
    const canvas = document.createElement("canvas");
    canvas.width = img.naturalWidth;
    canvas.height = img.naturalHeight;
    const g = canvas.getContext("2d");
    g.drawImage(img, 0, 0);
    const { data, width, height } = g.getImageData(0, 0, canvas.width, canvas.height);
    const out = [];
    for (let by = 0; by + 8 <= height; by += 8)
      for (let bx = 0; bx + 8 <= width; bx += 8) {
        let sum = 0;
        for (let y = by; y < by + 8; y++) for (let x = bx; x < bx + 8; x++) sum += data[4 * (y * width + x)];
        out.push(sum / 64);
      }
    return out;
  });
}
const largestChange = (a, b) => a.reduce((m, v, i) => Math.max(m, Math.abs(v - b[i])), 0);
/** The controls and HUD figures shown on `page` that lie outside its viewport (or have no
 *  width): their ids, or their first words. */
async function outOfView(page) {
  return page.evaluate(() =>
    [...document.querySelectorAll("#controls button, #controls input, #controls select, #hud dd")]
      .filter((e) => e.checkVisibility())
      .map((e) => ({ id: e.id || e.textContent?.trim().slice(0, 20), r: e.getBoundingClientRect() }))
      .filter(({ r }) => r.bottom > innerHeight + 0.5 || r.right > innerWidth + 0.5 || r.width === 0)
      .map(({ id }) => id),
  );
}

async function nextFrame(page, selector = "#xray") {
  const now = await page.$eval(selector, (img) => Number(img.dataset.frame ?? -1));
  await page.waitForFunction(
    ([s, n]) => {
      const img = document.querySelector(s);
      return Number(img?.dataset.frame ?? -1) > n && img.complete && img.naturalWidth > 0;
    },
    [selector, now],
    { timeout: 15_000 },
  );
}

/** A stand-in for a server a link might name (an attacker's): answers every request (CORS
 *  preflights let through, so that a page that meant to send a credential would send it) and
 *  records each, with its headers and body. */
async function startStandIn() {
  const requests = [];
  const standIn = createServer((req, res) => {
    const chunks = [];
    req.on("data", (c) => chunks.push(c));
    req.on("end", () => {
      requests.push({ method: req.method, url: req.url, headers: req.headers, body: Buffer.concat(chunks).toString("latin1") });
      const cors = {
        "access-control-allow-origin": req.headers.origin ?? "*",
        "access-control-allow-credentials": "true",
        "access-control-allow-methods": "GET, POST, OPTIONS",
        "access-control-allow-headers": req.headers["access-control-request-headers"] ?? "*",
        "access-control-expose-headers": "*",
      };
      if (req.method === "OPTIONS") res.writeHead(204, cors).end();
      else res.writeHead(404, { ...cors, "content-type": "text/plain" }).end("stand-in\n");
    });
  });
  await new Promise((r) => standIn.listen(0, "127.0.0.1", r));
  return { url: `http://127.0.0.1:${standIn.address().port}`, requests, close: () => standIn.close() };
}

/** The page's secrets in its address (after the page has run). */
const secretsInAddress = (page) =>
  page.evaluate(() => ["account", "token", "key"].filter((k) => new URL(location.href).searchParams.has(k)));

const results = [];
async function test(name, body) {
  if (only && !new RegExp(only).test(name)) return;
  const started = Date.now();
  try {
    await body();
    results.push({ name, ok: true });
    console.log(`test ${name} ... ok (${((Date.now() - started) / 1000).toFixed(1)} s)`);
  } catch (e) {
    results.push({ name, ok: false });
    console.log(`test ${name} ... FAILED\n  ${e.stack ?? e}`);
  }
}

const dir = mkdtempSync(join(tmpdir(), "cathlab-e2e-"));
let { child: server, url } = await startServer(dir);
const browser = await chromium.launch({
  executablePath: chromiumPath,
  args: [
    "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
  ],
});
// The trainee and the instructor are different people on different machines: separate
// browser contexts (separate connection pools, storage and focus).
const context = await browser.newContext({ viewport: { width: 1280, height: 860 } });
const instructor = await browser.newContext({ viewport: { width: 1280, height: 860 } });
const pageErrors = [];
const trainee = await context.newPage();
trainee.on("pageerror", (e) => pageErrors.push(`trainee: ${e.message}`));
if (process.env.E2E_DEBUG) {
  trainee.on("console", (m) => console.log(`  [trainee console] ${m.text()}`));
  trainee.on("response", (r) => console.log(`  [trainee] ${r.status()} ${r.url()}`));
}
let sessionId = "";
let toGoAtStart = Number.NaN;

try {
  // Links that name another server: nothing this browser keeps goes there. Each page is
  // opened with an account token and the instructor key in its storage (as the trainee page
  // and the dashboard keep them) by a link naming a stand-in on another port.
  const ACCOUNT_KEY = "cathlab.account.token";
  const INSTRUCTOR_KEY = "cathlab.instructor.key";
  const STORED_ACCOUNT = "e2e-stored-account-token-must-not-leave";
  await test("links_naming_another_server_send_it_nothing", async () => {
    const standIn = await startStandIn();
    const machine = await browser.newContext({ viewport: { width: 1280, height: 860 } });
    try {
      const page = await machine.newPage();
      page.on("pageerror", (e) => pageErrors.push(`another server: ${e.message}`));
      // The stored credentials, set on this origin (a page that makes no call: no session).
      await page.goto(`${url}/report.html`);
      await page.evaluate(
        ([a, k, account, key]) => {
          localStorage.setItem(a, account);
          localStorage.setItem(k, key);
        },
        [ACCOUNT_KEY, INSTRUCTOR_KEY, STORED_ACCOUNT, KEY],
      );
      const server = encodeURIComponent(standIn.url);
      for (const [path, message] of [
        [`/report.html?server=${server}&session=0123456789abcdef0123456789abcdef&token=e2e-link-token`, "#report-error"],
        [`/dashboard.html?server=${server}`, "#message"],
        [`/?server=${server}&scene=arch_to_cow_lcca`, "#message"],
        [`/?server=${server}&session=0123456789abcdef&token=e2e-link-token&account=e2e-link-account`, "#message"],
      ]) {
        await page.goto(`${url}${path}`);
        await page.waitForSelector('body[data-server="refused"]', { timeout: 10_000 });
        const said = await page.textContent(message);
        assert(await page.isVisible(message), `${path}: the message is shown`);
        assert(said.includes(standIn.url) && /Nothing was sent/.test(said), `${path}: the page says why: ${said}`);
        assert(await page.isVisible("#this-server"), `${path}: a link to this server's page`);
        assert((await secretsInAddress(page)).length === 0, `${path}: secrets left the address`);
        // Time for any call the page might still make.
        await page.waitForTimeout(300);
      }
      console.log(`  e.g. ${await page.textContent("#message")}`);
      const stored = await page.evaluate(([a]) => localStorage.getItem(a), [ACCOUNT_KEY]);
      assert(stored === STORED_ACCOUNT, `a link's account replaced the stored one: ${stored}`);
      const leaked = standIn.requests.filter((r) =>
        [STORED_ACCOUNT, KEY, "e2e-link-token", "e2e-link-account"].some(
          (secret) => JSON.stringify(r.headers).includes(secret) || r.body.includes(secret) || r.url.includes(secret),
        ),
      );
      assert(leaked.length === 0, `credentials sent to the stand-in: ${JSON.stringify(leaked)}`);
      assert(
        standIn.requests.length === 0,
        `the stand-in got requests: ${standIn.requests.map((r) => `${r.method} ${r.url}`).join(", ")}`,
      );
    } finally {
      await machine.close();
      standIn.close();
    }
  });

  await test("a_link_key_is_not_kept_or_used_until_connect", async () => {
    const machine = await browser.newContext({ viewport: { width: 1280, height: 860 } });
    try {
      const page = await machine.newPage();
      page.on("pageerror", (e) => pageErrors.push(`link key: ${e.message}`));
      await page.goto(`${url}/report.html`);
      await page.evaluate(([k, key]) => localStorage.setItem(k, key), [INSTRUCTOR_KEY, KEY]);
      await page.goto(`${url}/dashboard.html?key=e2e-link-key`);
      assert((await secretsInAddress(page)).length === 0, "the key left the address");
      await page.waitForFunction(() => /not used or kept/.test(document.querySelector("#message")?.textContent ?? ""), null, {
        timeout: 10_000,
      });
      const kept = await page.evaluate(([k]) => localStorage.getItem(k), [INSTRUCTOR_KEY]);
      assert(kept === KEY, `the link's key replaced the stored one: ${kept}`);
      assert((await page.inputValue("#key")) === "e2e-link-key", "the link's key waits in the form");
    } finally {
      await machine.close();
    }
  });

  await test("trainee_page_loads_and_connects", async () => {
    // The one-device scene (the default is coaxial: the two-hand tests below take it).
    await trainee.goto(`${url}/?label=e2e-trainee&scene=arch_to_cow_lcca`);
    await trainee.waitForSelector('#connection[data-status="connected"]', { timeout: 30_000 });
    sessionId = await trainee.$eval("body", (b) => b.dataset.session ?? "");
    assert(/^[0-9a-f-]{8,}$/.test(sessionId), `session id on the page: ${sessionId}`);
    assert((await trainee.textContent("#scene")).includes("arch_to_cow_lcca"), "scene name shown");
    assert((await trainee.$$eval("#device option", (o) => o.length)) === 3, "the scene's three devices listed");
    assert(new URL(trainee.url()).searchParams.get("session") === sessionId, "session kept in the URL for reloads");
    // Before the pedal: a prompt saying what to press, not a broken image.
    assert(await trainee.isVisible("#prompt"), "the fluoroscopy prompt shows before the pedal");
    assert((await trainee.textContent("#prompt")).includes("F"), "the prompt names the key");
    assert(!(await trainee.isVisible("#xray")), "no empty image before the first exposure");
    // The target is named with the distance still to go along the route.
    await trainee.waitForFunction(() => / mm$/.test(document.querySelector("#hud-target")?.textContent ?? ""), null, {
      timeout: 10_000,
    });
    toGoAtStart = Number.parseFloat(/· ([0-9.]+) mm/.exec(await trainee.textContent("#hud-target"))?.[1] ?? "NaN");
    assert((await trainee.textContent("#hud-target")).startsWith("LCCA"), "the target named");
    assert(toGoAtStart > 100, `distance to go at the start: ${toGoAtStart} mm`);
  });

  // After the first session: the scene is loaded, so this one's session starts at once.
  await test("a_sign_in_link_changes_the_account_only_when_the_trainee_accepts", async () => {
    const machine = await browser.newContext({ viewport: { width: 1280, height: 860 } });
    try {
      // Two trainee accounts: this browser's, and the one in someone else's link.
      const dash = await machine.newPage();
      dash.on("pageerror", (e) => pageErrors.push(`dashboard (link sign-in): ${e.message}`));
      await dash.goto(`${url}/dashboard.html`);
      await dash.fill("#key", KEY);
      await dash.click('#key-form button[type="submit"]');
      await dash.click("#accounts-box summary");
      const account = async (name) => {
        const before = await dash.evaluate(() => document.querySelector("#account-url")?.getAttribute("href") ?? null);
        await dash.fill("#account-name", name);
        await dash.click('#new-account button[type="submit"]');
        await dash.waitForFunction(
          (b) => document.querySelector("#account-url") && document.querySelector("#account-url").getAttribute("href") !== b,
          before,
          { timeout: 30_000 },
        );
        return new URL(await dash.getAttribute("#account-url", "href")).searchParams.get("account");
      };
      const mine = await account("e2e Own Trainee");
      const theirs = await account("e2e Link Sender");
      assert(mine && theirs && mine !== theirs, "two accounts made");
      await dash.close();
      const page = await machine.newPage();
      page.on("pageerror", (e) => pageErrors.push(`link sign-in: ${e.message}`));
      await page.goto(`${url}/report.html`);
      await page.evaluate(([a, t]) => localStorage.setItem(a, t), [ACCOUNT_KEY, mine]);
      await page.goto(`${url}/?account=${encodeURIComponent(theirs)}&scene=arch_to_cow_lcca&label=e2e-link-sign-in`);
      assert((await secretsInAddress(page)).length === 0, `the token left the address: ${page.url()}`);
      assert(!page.url().includes(theirs), "the token is nowhere in the address");
      await page.waitForSelector("#account-offer:not([hidden])", { timeout: 10_000 });
      await page.waitForFunction(
        () => /Link Sender/.test(document.querySelector("#account-offer")?.textContent ?? "") &&
          /Own Trainee/.test(document.querySelector("#account-offer")?.textContent ?? ""),
        null,
        { timeout: 10_000 },
      );
      console.log(`  ${(await page.textContent("#account-offer")).replace(/\s+/g, " ").trim()}`);
      await page.waitForTimeout(500);
      const stored = () => page.evaluate(([a]) => localStorage.getItem(a), [ACCOUNT_KEY]);
      assert((await stored()) === mine, "the link changed the stored account before the trainee answered");
      assert(!(await page.$eval("body", (b) => b.dataset.session)), "no session before the trainee answered");
      // Ignored: this browser's account stays, and the session is made with it.
      await page.click("#account-ignore");
      assert(!(await page.isVisible("#account-offer")), "the question goes");
      await page.waitForFunction(() => /Own Trainee/.test(document.querySelector("#account")?.textContent ?? ""), null, {
        timeout: 60_000,
      });
      assert((await stored()) === mine, "ignoring the link kept the stored account");
      // Finished at once: the session does not load the machine for the tests after this one.
      await page.waitForSelector('#connection[data-status="connected"]', { timeout: 60_000 });
      await page.click("#finish");
      await page.waitForSelector("#report-link", { timeout: 10_000 });
      // A reload has no token to offer again.
      await page.goto(`${url}/report.html`);
      assert((await stored()) === mine, "the stored account stayed");
    } finally {
      await machine.close();
    }
  });

  await test("fluoroscopy_frames_render_and_change_after_a_push", async () => {
    await trainee.bringToFront();
    await trainee.click("#screen"); // focus the page, not a form field
    await trainee.keyboard.down("f");
    await nextFrame(trainee);
    await nextFrame(trainee);
    const a = await blocks(trainee, "#xray");
    await nextFrame(trainee);
    const b = await blocks(trainee, "#xray");
    const noise = largestChange(a, b);
    const before = millimetres(await trainee.textContent("#hud-inserted"));
    await trainee.keyboard.down("ArrowUp");
    // The HUD's wall force while the shaped tip rides along the aortic wall.
    let wallForce = 0;
    for (let i = 0; i < 20; i++) {
      await trainee.waitForTimeout(100);
      wallForce = Math.max(wallForce, Number.parseFloat(await trainee.textContent("#hud-force")));
    }
    await trainee.keyboard.up("ArrowUp");
    await trainee.waitForTimeout(300);
    await nextFrame(trainee);
    await nextFrame(trainee);
    const c = await blocks(trainee, "#xray");
    const moved = largestChange(b, c);
    const after = millimetres(await trainee.textContent("#hud-inserted"));
    console.log(`  inserted ${before} → ${after} mm; largest 8×8-block change ${moved.toFixed(1)} grey levels (frame-to-frame noise ${noise.toFixed(1)})`);
    assert(after - before > 20 && after - before < 60, `↑ held 2 s at 20 mm/s advanced ${after - before} mm`);
    console.log(`  largest wall force on the HUD during the push: ${wallForce} mN`);
    assert(wallForce > 0, "the HUD shows the wall contact force");
    assert(moved > 3 * noise && moved > 10, `the image changed after the push: ${moved} vs noise ${noise}`);
    assert((await trainee.textContent("#mode")).startsWith("FLUORO"), "fluoroscopy mode shown");
    assert(!(await trainee.isVisible("#prompt")), "the prompt is gone once frames arrive");
    const dose = await trainee.textContent("#dose");
    console.log(`  dose display: ${dose}`);
    const kerma = Number.parseFloat(/Ka,r ([0-9.]+) mGy/.exec(dose)?.[1] ?? "NaN");
    assert(kerma > 0, `the dose display shows the accumulated reference air kerma: ${dose}`);
    // After ~40 mm of push the route to go is shorter (metrics come once a second).
    await trainee.waitForTimeout(1200);
    const toGo = Number.parseFloat(/· ([0-9.]+) mm/.exec(await trainee.textContent("#hud-target"))?.[1] ?? "NaN");
    console.log(`  to go: ${toGoAtStart} → ${toGo} mm`);
    assert(toGoAtStart - toGo > 15, `the distance to go fell by ${toGoAtStart - toGo} mm`);
    await trainee.screenshot({ path: join(artifacts, "trainee.png") });
    await trainee.keyboard.up("f");
  });

  await test("on_screen_buttons_pull_back", async () => {
    const before = millimetres(await trainee.textContent("#hud-inserted"));
    const button = await trainee.$('#right-hand button[data-hold="pull"]');
    const box = await button.boundingBox();
    await trainee.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
    await trainee.mouse.down();
    await trainee.waitForTimeout(1000);
    await trainee.mouse.up();
    await trainee.waitForTimeout(300);
    const after = millimetres(await trainee.textContent("#hud-inserted"));
    assert(before - after > 10, `the pull button withdrew ${before - after} mm`);
  });

  await test("keys_drive_the_device_with_a_slider_or_a_dropdown_focused", async () => {
    for (const control of ["#primary", "#pulse"]) {
      await trainee.focus(control);
      const value = await trainee.$eval(control, (e) => e.value);
      const before = millimetres(await trainee.textContent("#hud-inserted"));
      await trainee.keyboard.down("ArrowUp");
      await trainee.waitForTimeout(1000);
      await trainee.keyboard.up("ArrowUp");
      await trainee.waitForTimeout(300);
      const after = millimetres(await trainee.textContent("#hud-inserted"));
      console.log(`  ${control} focused: ↑ moved the device ${before} → ${after} mm`);
      assert(after - before > 10, `↑ with ${control} focused advanced ${after - before} mm`);
      assert((await trainee.$eval(control, (e) => e.value)) === value, `${control} kept its value`);
      assert(await trainee.$eval(control, (e) => document.activeElement === e), `${control} kept the focus`);
    }
    await trainee.click("#screen");
  });

  await test("a_dsa_run_shows_the_arch_vessels_on_the_roadmap_with_the_target_marked", async () => {
    await trainee.bringToFront();
    await trainee.click("#screen");
    await trainee.keyboard.down("f");
    await nextFrame(trainee);
    // A DSA run fires the injector after its mask; the contrast reaches the branches.
    await trainee.click("#dsa");
    await trainee.waitForFunction(() => document.querySelector("#mode")?.textContent?.startsWith("DSA"), null, {
      timeout: 15_000,
    });
    // A run of 8 s, as for an arch angiogram: the contrast rises from the descending aorta
    // through the arch into the branches.
    await trainee.waitForTimeout(8000);
    await trainee.click("#dsa");
    await trainee.click("#screen");
    await trainee.click("#roadmap");
    await trainee.waitForFunction(() => document.querySelector("#mode")?.textContent?.startsWith("ROADMAP"), null, {
      timeout: 15_000,
    });
    await nextFrame(trainee);
    await nextFrame(trainee);
    await trainee.waitForSelector('#target-marker[data-visible="true"]', { timeout: 10_000 });
    // Along the marked target (the LCCA from its origin on the arch) against the body
    // around it: the vessel map's contrast over the background noise.
    const measured = await trainee.evaluate(() => {
      const img = document.querySelector("#xray");
      const canvas = document.createElement("canvas");
      canvas.width = img.naturalWidth;
      canvas.height = img.naturalHeight;
      const g = canvas.getContext("2d");
      g.drawImage(img, 0, 0);
      const { data, width, height } = g.getImageData(0, 0, canvas.width, canvas.height);
      const at = (x, y) => data[4 * (Math.round(y) * width + Math.round(x))];
      const points = document
        .querySelector("#target-marker polyline")
        .getAttribute("points")
        .trim()
        .split(/\s+/)
        .map((p) => p.split(",").map(Number))
        .map(([x, y]) => [x * width, y * height]);
      const inside = points.filter(([x, y]) => x >= 2 && y >= 2 && x < width - 2 && y < height - 2);
      const median = (v) => {
        const s = [...v].sort((a, b) => a - b);
        return s[Math.floor(s.length / 2)];
      };
      const vessel = median(inside.map(([x, y]) => at(x, y)));
      // Background: a ring 25–45 px round the marked vessel, 12 px or more from it.
      const near = (x, y, r) => inside.some(([px, py]) => (px - x) ** 2 + (py - y) ** 2 < r * r);
      const ring = [];
      for (let y = 0; y < height; y += 2)
        for (let x = 0; x < width; x += 2) if (near(x, y, 45) && !near(x, y, 25)) ring.push(at(x, y));
      const background = median(ring);
      const noise = 1.4826 * median(ring.map((v) => Math.abs(v - background)));
      return { points: inside.length, vessel, background, noise };
    });
    const ratio = Math.abs(measured.vessel - measured.background) / Math.max(measured.noise, 0.5);
    console.log(
      `  roadmap: ${measured.points} marker points; vessel ${measured.vessel} vs background ${measured.background} ± ${measured.noise.toFixed(2)} grey levels: contrast ${ratio.toFixed(1)}× the noise`,
    );
    await trainee.screenshot({ path: join(artifacts, "trainee-roadmap.png") });
    assert(measured.points >= 10, `the target marker has ${measured.points} points in the image`);
    assert(ratio >= 5, `the vessel map's contrast is ${ratio.toFixed(1)}× the background noise`);
    await trainee.click("#roadmap");
    await trainee.keyboard.up("f");
  });

  let observer;
  await test("dashboard_lists_the_session_with_thumbnail_metrics_and_timeline", async () => {
    const dashboard = await instructor.newPage();
    dashboard.on("pageerror", (e) => pageErrors.push(`dashboard: ${e.message}`));
    // The key goes into the form, never into a URL.
    await dashboard.goto(`${url}/dashboard.html`);
    await dashboard.fill("#key", KEY);
    await dashboard.click('#key-form button[type="submit"]');
    const card = `.card[data-session="${sessionId}"]`;
    await dashboard.waitForSelector(card, { timeout: 15_000 });
    const title = await dashboard.textContent(`${card} h3`);
    assert(title.includes("e2e-trainee") && title.includes("arch_to_cow_lcca") && title.includes("started"), `the card's title: ${title}`);
    // A live thumbnail: fluoroscopy on again, frames arrive on the card.
    await trainee.bringToFront();
    await trainee.keyboard.down("f");
    await dashboard.bringToFront();
    await nextFrame(dashboard, `${card} img`);
    await dashboard.waitForFunction((c) => document.querySelector(`${c} dl`)?.textContent?.includes("Fluoro"), card);
    await dashboard.click(`${card} button`);
    await dashboard.waitForFunction(
      () => [...document.querySelectorAll("#timeline li.imaging")].some((li) => li.textContent.includes("fluoroscopy on")),
      null,
      { timeout: 10_000 },
    );
    // Reset starts a new attempt, and the dashboard counts it.
    await trainee.bringToFront();
    await trainee.click("#reset");
    await dashboard.bringToFront();
    await dashboard.waitForFunction(
      (c) => /Resets\s*1\b/.test(document.querySelector(`${c} dl`)?.textContent ?? ""),
      card,
      { timeout: 10_000 },
    );
    await dashboard.screenshot({ path: join(artifacts, "dashboard.png") });
    const href = await dashboard.$eval(`${card} a`, (a) => a.href);
    const hrefs = await dashboard.$$eval("a", (links) => links.map((a) => a.href));
    assert(![dashboard.url(), ...hrefs].some((u) => u.includes(KEY)), "no URL carries the instructor key");
    observer = await instructor.newPage();
    observer.on("pageerror", (e) => pageErrors.push(`observer: ${e.message}`));
    await observer.goto(href);
    await trainee.bringToFront();
    await trainee.keyboard.up("f");
  });

  await test("the_observer_view_cannot_command", async () => {
    assert(observer, "opened from the dashboard");
    await observer.bringToFront();
    await observer.waitForSelector('#connection[data-status="connected"]', { timeout: 15_000 });
    assert((await observer.textContent("#role")).includes("read-only"), "marked read-only");
    const enabled = await observer.$$eval("#controls button, #controls input, #controls select", (els) =>
      els.filter((e) => !e.disabled).length,
    );
    assert(enabled === 0, `${enabled} controls enabled in the observer view`);
    // "connected" can show before the first device state fills the HUD.
    await observer.waitForFunction(
      () => Number.isFinite(Number.parseFloat(document.querySelector("#hud-inserted")?.textContent ?? "")),
      null,
      { timeout: 15_000 },
    );
    const before = millimetres(await observer.textContent("#hud-inserted"));
    await observer.click("#screen");
    await observer.keyboard.down("ArrowUp");
    await observer.waitForTimeout(1500);
    await observer.keyboard.up("ArrowUp");
    await observer.waitForTimeout(300);
    const after = millimetres(await observer.textContent("#hud-inserted"));
    assert(Number.isFinite(before) && Math.abs(after - before) < 0.01, `observer keys moved the device ${before} → ${after}`);
    // The same keys in the trainee view still work (the session is live, not frozen).
    await trainee.bringToFront();
    await trainee.keyboard.down("ArrowUp");
    await trainee.waitForTimeout(1000);
    await trainee.keyboard.up("ArrowUp");
    await trainee.waitForTimeout(300);
    const pushed = millimetres(await trainee.textContent("#hud-inserted"));
    await observer.bringToFront();
    await observer.waitForTimeout(500);
    const moved = millimetres(await observer.textContent("#hud-inserted"));
    console.log(`  trainee pushed to ${pushed} mm; the observer shows ${moved} mm`);
    assert(moved - after > 10, `the observer sees the trainee's push: ${after} → ${moved}`);
  });

  await test("an_instructor_starts_an_assessment_session_without_guidance", async () => {
    // A second instructor machine: the first one's pages hold its six HTTP/1.1 connections.
    const dashboard = await (await browser.newContext({ viewport: { width: 1280, height: 860 } })).newPage();
    dashboard.on("pageerror", (e) => pageErrors.push(`dashboard: ${e.message}`));
    await dashboard.goto(`${url}/dashboard.html`);
    await dashboard.click("#new-session-box summary");
    await dashboard.waitForFunction(() => document.querySelectorAll("#new-scene option").length > 0);
    await dashboard.fill("#new-label", "e2e-assessed");
    await dashboard.check("#new-assessment");
    await dashboard.click('#new-session button[type="submit"]');
    await dashboard.waitForFunction(() => document.querySelector("#new-link")?.textContent, null, { timeout: 30_000 });
    const started = await dashboard.textContent("#new-link");
    console.log(`  ${started}`);
    assert(await dashboard.$("#trainee-link"), `the dashboard gives the trainee's link: ${started}`);
    const link = await dashboard.$eval("#trainee-link", (a) => a.href);
    assert(!link.includes(KEY), "the trainee's link carries no instructor key");
    const assessed = await (await browser.newContext({ viewport: { width: 1280, height: 860 } })).newPage();
    assessed.on("pageerror", (e) => pageErrors.push(`assessed: ${e.message}`));
    await assessed.goto(link);
    await assessed.waitForSelector('#connection[data-status="connected"]', { timeout: 30_000 });
    assert((await assessed.$eval("body", (b) => b.dataset.guidance)) === "off", "the page knows guidance is off");
    assert(!(await assessed.isVisible("#prompt")), "no prompt in an assessment");
    assert((await assessed.textContent("#hud-target-title")) === "Target", "no distance heading");
    await assessed.waitForTimeout(1500);
    assert(!/mm/.test(await assessed.textContent("#hud-target")), "no remaining distance");
    await assessed.click("#screen");
    await assessed.keyboard.down("f");
    await assessed.click("#dsa");
    await assessed.waitForFunction(() => document.querySelector("#mode")?.textContent?.startsWith("DSA"), null, {
      timeout: 15_000,
    });
    await nextFrame(assessed);
    assert(
      (await assessed.$eval("#target-marker", (m) => m.dataset.visible)) !== "true",
      "no target marker in an assessment",
    );
    await assessed.keyboard.up("f");
    await assessed.close();
    await dashboard.close();
  });

  await test("two_hands_drive_their_own_instruments_the_stack_panel_and_the_observer_follow", async () => {
    // A trainee on another machine, on the default scene (coaxial: catheter over a wire).
    const machine = await browser.newContext({ viewport: { width: 1280, height: 800 } });
    const hands = await machine.newPage();
    hands.on("pageerror", (e) => pageErrors.push(`two hands: ${e.message}`));
    await hands.goto(`${url}/?label=e2e-two-hands`);
    await hands.waitForSelector('#connection[data-status="connected"]', { timeout: 30_000 });
    const scene = await hands.textContent("#scene");
    assert(scene.includes("arch_to_cow_lcca_coaxial"), `the default scene is the coaxial one: ${scene}`);
    assert(await hands.isVisible("#left-hand"), "the left hand's controls show");
    assert(!(await hands.isVisible("#device-choice")), "no device list in a coaxial scene");
    await hands.waitForFunction(() => document.querySelectorAll("#stack li").length === 2, null, { timeout: 15_000 });
    const row = async (page, i) =>
      page.$eval(`#stack li[data-instrument="${i}"]`, (li) => ({
        name: li.querySelector(".name").textContent,
        inserted: Number.parseFloat(li.querySelector(".inserted").textContent.replace("−", "-")),
        relative: li.querySelector(".relative").textContent,
      }));
    const out = (r) => {
      const m = /([\d.]+) mm (out of|inside)/.exec(r.relative);
      return m ? (m[2] === "inside" ? -1 : 1) * Number(m[1]) : 0;
    };
    const hold = async (page, key, ms) => {
      await page.keyboard.down(key);
      await page.waitForTimeout(ms);
      await page.keyboard.up(key);
      await page.waitForTimeout(400);
    };
    await hands.click("#screen");
    const c0 = await row(hands, 0);
    const w0 = await row(hands, 1);
    console.log(`  start: ${c0.name} ${c0.inserted} mm; ${w0.name} ${w0.inserted} mm, ${w0.relative}`);
    // The right hand (arrows) drives the wire only.
    await hold(hands, "ArrowUp", 1000);
    const c1 = await row(hands, 0);
    const w1 = await row(hands, 1);
    console.log(`  ↑ 1 s: catheter ${c1.inserted} mm; wire ${w1.inserted} mm, ${w1.relative}`);
    assert(w1.inserted - w0.inserted > 10, `the right hand pushed the wire ${w1.inserted - w0.inserted} mm`);
    assert(Math.abs(c1.inserted - c0.inserted) < 1, `the catheter stayed: ${c0.inserted} → ${c1.inserted}`);
    assert(out(w1) - out(w0) > 10, `the panel's tip offset follows: ${w0.relative} → ${w1.relative}`);
    // The left hand (W) drives the catheter only: it follows over the wire.
    await hold(hands, "w", 1000);
    const c2 = await row(hands, 0);
    const w2 = await row(hands, 1);
    console.log(`  W 1 s: catheter ${c2.inserted} mm; wire ${w2.inserted} mm, ${w2.relative}`);
    assert(c2.inserted - c1.inserted > 10, `the left hand pushed the catheter ${c2.inserted - c1.inserted} mm`);
    assert(Math.abs(w2.inserted - w1.inserted) < 1, `the wire stayed: ${w1.inserted} → ${w2.inserted}`);
    assert(out(w1) - out(w2) > 10, `the wire's lead shrank as the catheter followed: ${w1.relative} → ${w2.relative}`);
    // The left hand's on-screen button pulls the catheter back.
    const button = await hands.$('#left-hand button[data-hold="pull"]');
    const box = await button.boundingBox();
    await hands.mouse.move(box.x + box.width / 2, box.y + box.height / 2);
    await hands.mouse.down();
    await hands.waitForTimeout(600);
    await hands.mouse.up();
    await hands.waitForTimeout(400);
    const c3 = await row(hands, 0);
    assert(c2.inserted - c3.inserted > 5, `the left pull button withdrew the catheter ${c2.inserted - c3.inserted} mm`);
    // Every control of the two-hand page is in view at 1280×800 (two columns of controls).
    const outside = await hands.evaluate(() =>
      [...document.querySelectorAll("#controls button, #controls input, #controls select, #hud dd")]
        .filter((e) => e.checkVisibility())
        .map((e) => ({ id: e.id || e.textContent?.trim().slice(0, 20), r: e.getBoundingClientRect() }))
        .filter(({ r }) => r.bottom > innerHeight + 0.5 || r.right > innerWidth + 0.5 || r.width === 0)
        .map(({ id }) => id),
    );
    assert(outside.length === 0, `out of view on the two-hand page at 1280×800: ${outside.join(", ")}`);
    // The README's picture: fluoroscopy on, both instruments in the image.
    await hands.keyboard.down("f");
    await nextFrame(hands);
    await nextFrame(hands);
    await hands.screenshot({ path: join(artifacts, "trainee-two-hands.png") });
    await hands.keyboard.up("f");
    // The observer, from an instructor's dashboard, sees both instruments move.
    const desk = await browser.newContext({ viewport: { width: 1280, height: 860 } });
    const dashboard = await desk.newPage();
    dashboard.on("pageerror", (e) => pageErrors.push(`dashboard (two hands): ${e.message}`));
    await dashboard.goto(`${url}/dashboard.html`);
    await dashboard.fill("#key", KEY);
    await dashboard.click('#key-form button[type="submit"]');
    const id = await hands.$eval("body", (b) => b.dataset.session ?? "");
    const card = `.card[data-session="${id}"]`;
    await dashboard.waitForSelector(card, { timeout: 15_000 });
    const href = await dashboard.$eval(`${card} a`, (a) => a.href);
    await dashboard.close();
    const watcher = await desk.newPage();
    watcher.on("pageerror", (e) => pageErrors.push(`observer (two hands): ${e.message}`));
    await watcher.goto(href);
    await watcher.waitForFunction(() => document.querySelectorAll("#stack li").length === 2, null, { timeout: 15_000 });
    await hands.bringToFront();
    await hold(hands, "ArrowUp", 700);
    await hold(hands, "w", 700);
    // Both pages' figures once they have settled (a loaded machine delays states).
    const settled = async (page) => {
      let last = "";
      for (let i = 0; i < 20; i++) {
        const now = [await row(page, 0), await row(page, 1)];
        const key = JSON.stringify(now.map((r) => r.inserted));
        if (key === last) return now;
        last = key;
        await page.waitForTimeout(300);
      }
      throw new Error(`the figures never settled: ${last}`);
    };
    const seen = await settled(hands);
    await watcher.bringToFront();
    const watched = await settled(watcher);
    console.log(`  trainee ${seen.map((r) => r.inserted).join(" / ")} mm; observer ${watched.map((r) => r.inserted).join(" / ")} mm`);
    for (const i of [0, 1]) {
      assert(Math.abs(seen[i].inserted - watched[i].inserted) < 1, `observer's instrument ${i}: ${watched[i].inserted} vs ${seen[i].inserted}`);
    }
    assert(seen[0].inserted - c3.inserted > 5 && seen[1].inserted - w2.inserted > 5, "both instruments moved again");
    await watcher.close();
    await desk.close();
    // An exchange from the page: the wire drawn back through the catheter (the panel
    // follows), a catalogue wire in its place at the hub.
    await hands.bringToFront();
    const wireBefore = (await row(hands, 1)).inserted;
    await hands.selectOption("#exchange-device", "catalogue:guidewire-035-j-3mm");
    await hands.click("#exchange-go");
    await hands.waitForFunction(() => /withdrawing/.test(document.querySelector("#message")?.textContent ?? ""), null, {
      timeout: 10_000,
    });
    console.log(`  exchange: ${await hands.textContent("#message")}`);
    await hands.waitForTimeout(1000);
    const withdrawing = (await row(hands, 1)).inserted;
    assert(withdrawing < wireBefore - 50, `the wire is being withdrawn: ${wireBefore} → ${withdrawing} mm`);
    await hands.waitForFunction(() => /J-tip/.test(document.querySelector('#stack li[data-instrument="1"] .name')?.textContent ?? ""), null, {
      timeout: 20_000,
    });
    const fresh = await row(hands, 1);
    console.log(`  after the exchange: ${fresh.name} at ${fresh.inserted} mm, ${fresh.relative}`);
    assert((await hands.textContent("#right-instrument")).includes("J-tip"), "the right hand now holds the new wire");
    assert(/inside/.test(fresh.relative), `the new wire waits inside the catheter: ${fresh.relative}`);
    // A device that cannot go in is refused with the server's reason, and nothing changes.
    await hands.selectOption("#exchange-device", "catalogue:guide-6f-071-90");
    await hands.click("#exchange-go");
    await hands.waitForFunction(() => !/withdrawing/.test(document.querySelector("#message")?.textContent ?? ""), null, {
      timeout: 10_000,
    });
    const refusal = await hands.textContent("#message");
    console.log(`  refused: ${refusal}`);
    assert(refusal.length > 10, "the page says why the exchange was refused");
    assert((await hands.textContent("#right-instrument")).includes("J-tip"), "the refused exchange left the wire");
    await machine.close();
  });

  await test("stroke_scene_thrombectomy_panel_grade_and_demonstration", async () => {
    const machine = await browser.newContext({ viewport: { width: 1280, height: 800 } });
    const page = await machine.newPage();
    page.on("pageerror", (e) => pageErrors.push(`stroke: ${e.message}`));
    const message = () => page.textContent("#message");
    // The stroke scene (its anatomy takes a while to build on first use).
    await page.goto(`${url}/?label=e2e-stroke&scene=stroke_m1_thrombectomy`);
    await page.waitForSelector('#connection[data-status="connected"]', { timeout: 120_000 });
    await page.waitForSelector("#thrombectomy:not([hidden])", { timeout: 15_000 });
    await page.waitForFunction(() => /^0 /.test(document.querySelector("#hud-etici")?.textContent ?? ""), null, {
      timeout: 15_000,
    });
    console.log(`  eTICI ${await page.textContent("#hud-etici")}, passes ${await page.textContent("#hud-passes")}`);
    // Deploying before a stent retriever is in: the server's reason on the page.
    await page.click("#deploy-stent");
    await page.waitForFunction(() => /stent retriever/.test(document.querySelector("#message")?.textContent ?? ""), null, {
      timeout: 10_000,
    });
    console.log(`  deploy refused: ${await message()}`);
    // Suction on: still on after the metrics polls (the server's figure).
    await page.click("#aspiration");
    await page.waitForTimeout(2500);
    assert((await page.getAttribute("#aspiration", "aria-pressed")) === "true", "suction stays on");
    await page.click("#aspiration");
    await page.waitForTimeout(2500);
    assert((await page.getAttribute("#aspiration", "aria-pressed")) === "false", "suction off again");
    // The scene's operator demonstrates the crossing: the microcatheter reaches beyond the clot.
    await page.click("#demonstrate");
    await page.waitForFunction(() => /reached/.test(document.querySelector("#hud-target")?.textContent ?? ""), null, {
      timeout: 120_000,
    });
    console.log(`  demonstration: ${await page.textContent("#hud-target")}`);
    // Every control of the stroke page is in view at 1280×800.
    const outside = await outOfView(page);
    assert(outside.length === 0, `out of view on the stroke page at 1280×800: ${outside.join(", ")}`);
    assert((await page.getAttribute("#demonstrate", "aria-pressed")) === "false", "the demonstration button released");
    await page.keyboard.down("f");
    await nextFrame(page);
    await nextFrame(page);
    await page.screenshot({ path: join(artifacts, "trainee-stroke.png") });
    await page.keyboard.up("f");
    await machine.close();
  });

  await test("access_scene_takes_the_innermost_out_and_loads_another", async () => {
    const machine = await browser.newContext({ viewport: { width: 1280, height: 800 } });
    const page = await machine.newPage();
    page.on("pageerror", (e) => pageErrors.push(`access: ${e.message}`));
    const count = () => page.evaluate(() => document.querySelectorAll("#stack li").length);
    await page.goto(`${url}/?label=e2e-access&scene=stroke_m1_from_access`);
    await page.waitForSelector('#connection[data-status="connected"]', { timeout: 120_000 });
    await page.waitForFunction(() => document.querySelectorAll("#stack li").length === 3, null, { timeout: 15_000 });
    // Every control of the page is in view at 1280×800, the loading buttons among them.
    const outside = await outOfView(page);
    assert(outside.length === 0, `out of view on the access page at 1280×800: ${outside.join(", ")}`);
    // The access wire out: drawn back to the hub, then off the table; the hands' lists follow.
    await page.click("#unload-go");
    await page.waitForFunction(() => document.querySelectorAll("#stack li").length === 2, null, { timeout: 60_000 });
    const leftOptions = await page.evaluate(() => document.querySelector("#left-instrument").options.length);
    assert(leftOptions === 1, `the left hand's list has the guide only: ${leftOptions}`);
    // A microcatheter loaded into the diagnostic catheter: the new innermost, in the right hand.
    await page.selectOption("#exchange-device", "catalogue:microcatheter-021-160");
    await page.click("#load-go");
    await page.waitForFunction(() => document.querySelectorAll("#stack li").length === 3, null, { timeout: 15_000 });
    const right = await page.textContent("#right-instrument");
    assert(/microcatheter/.test(right), `the right hand holds the microcatheter: ${right}`);
    console.log(`  stack of ${await count()}: right hand ${right}; ${await page.textContent("#message")}`);
    // Loading a catheter too wide for the microcatheter: the server's reason on the page.
    await page.selectOption("#exchange-device", "catalogue:distal-access-058-115");
    await page.click("#load-go");
    await page.waitForFunction(() => /fit/.test(document.querySelector("#message")?.textContent ?? ""), null, {
      timeout: 10_000,
    });
    console.log(`  refused: ${await page.textContent("#message")}`);
    assert((await count()) === 3, "nothing loaded");
    await machine.close();
  });

  await test("layouts_fit_1280x800_and_1024x640_without_scrolling", async () => {
    await trainee.bringToFront();
    for (const [width, height] of [[1280, 800], [1024, 640]]) {
      await trainee.setViewportSize({ width, height });
      await trainee.waitForTimeout(300);
      const layout = await trainee.evaluate(() => {
        const shown = [...document.querySelectorAll("#controls button, #controls input, #controls select, #hud dd")].filter(
          (e) => e.checkVisibility(),
        );
        const boxes = shown.map(
          (e) => {
            const r = e.getBoundingClientRect();
            return { id: e.id || e.textContent?.trim().slice(0, 20), bottom: r.bottom, right: r.right, width: r.width };
          },
        );
        const screen = document.querySelector("#screen").getBoundingClientRect();
        return {
          boxes,
          scroll: document.documentElement.scrollHeight - innerHeight,
          screen: { width: screen.width, height: screen.height },
        };
      });
      const outside = layout.boxes.filter((b) => b.bottom > height + 0.5 || b.right > width + 0.5 || b.width === 0);
      console.log(
        `  ${width}×${height}: image ${layout.screen.width.toFixed(0)}×${layout.screen.height.toFixed(0)} px; ${layout.boxes.length} controls, ${outside.length} out of view; page scrolls ${layout.scroll} px`,
      );
      await trainee.screenshot({ path: join(artifacts, `trainee-${width}x${height}.png`) });
      assert(outside.length === 0, `out of view at ${width}×${height}: ${JSON.stringify(outside)}`);
      assert(layout.scroll <= 0, `the page scrolls ${layout.scroll} px at ${width}×${height}`);
      assert(layout.screen.height >= height - 200, `the image uses the height: ${layout.screen.height} px`);
    }
    await trainee.setViewportSize({ width: 1280, height: 860 });
  });

  await test("a_trainee_finishes_two_sessions_and_reads_the_report_replay_csv_and_learning_curve", async () => {
    // The instructor makes the trainee's account on the dashboard, in a browser of its own
    // (the other instructor pages hold their streams' connections).
    const teaching = await browser.newContext({ viewport: { width: 1280, height: 900 } });
    const dash = await teaching.newPage();
    dash.on("pageerror", (e) => pageErrors.push(`dashboard (accounts): ${e.message}`));
    await dash.goto(`${url}/dashboard.html`);
    await dash.fill("#key", KEY);
    await dash.click('#key-form button[type="submit"]');
    await dash.click("#accounts-box summary");
    await dash.fill("#account-name", "Rita Trainee");
    await dash.click('#new-account button[type="submit"]');
    await dash.waitForFunction(() => document.querySelector("#account-link")?.textContent, null, { timeout: 30_000 });
    const made = await dash.textContent("#account-link");
    assert(await dash.$("#account-url"), `the account was not made: ${made}`);
    const signIn = new URL(await dash.getAttribute("#account-url", "href"));
    signIn.searchParams.set("scene", "arch_to_cow_lcca");
    const ritas = await browser.newContext({ viewport: { width: 1280, height: 900 }, acceptDownloads: true });
    const page = await ritas.newPage();
    page.on("pageerror", (e) => pageErrors.push(`report: ${e.message}`));
    const procedure = async (pushMs, firstVisit) => {
      await page.goto(signIn.toString());
      // A browser with no account asks before it keeps the link's; once kept, the same link
      // asks nothing.
      if (firstVisit) {
        await page.waitForSelector("#account-offer:not([hidden])", { timeout: 10_000 });
        await page.waitForFunction(() => /Rita Trainee/.test(document.querySelector("#account-offer-new")?.textContent ?? ""), null, {
          timeout: 10_000,
        });
        await page.click("#account-accept");
      }
      await page.waitForSelector('#connection[data-status="connected"]', { timeout: 30_000 });
      assert(!(await page.isVisible("#account-offer")), "no question once the account is kept");
      await page.waitForFunction(() => document.querySelector("#account")?.textContent?.includes("Rita"), null, {
        timeout: 10_000,
      });
      assert(!page.url().includes("account="), "the account token leaves the address bar");
      await page.click("#screen");
      await page.keyboard.down("f");
      await page.keyboard.down("ArrowUp");
      await page.waitForTimeout(pushMs);
      await page.keyboard.up("ArrowUp");
      await page.waitForTimeout(400);
      await page.keyboard.up("f");
      await page.click("#finish");
      await page.waitForSelector("#report-link", { timeout: 10_000 });
      return page.getAttribute("#report-link", "href");
    };
    await procedure(1500, true);
    const report = await procedure(2500, false);
    const asked = Date.now();
    await page.goto(report);
    await page.waitForSelector("body[data-ready='1'], #report-error:not([hidden])", { timeout: 120_000 });
    assert(
      (await page.getAttribute("body", "data-ready")) === "1",
      `the report is not shown: ${await page.textContent("#report-error")}`,
    );
    console.log(`  the report shown ${((Date.now() - asked) / 1000).toFixed(1)} s after it was asked for`);
    await page.screenshot({ path: join(artifacts, "report.png"), fullPage: true });
    const title = await page.textContent("#title");
    assert(title.includes("Rita Trainee") && title.includes("arch_to_cow_lcca"), `the report's title: ${title}`);
    // Scores, the timeline, four charts.
    const rows = await page.$$eval("#scores tbody tr", (r) => r.length);
    assert(rows >= 15, `${rows} scores`);
    const phases = await page.$$eval("#timeline .phase", (p) => p.map((x) => x.textContent));
    console.log(`  ${rows} scores; phases ${JSON.stringify(phases)}`);
    assert(phases.length >= 1 && phases[0].startsWith("access"), `phases on the timeline: ${phases}`);
    const charts = await page.$$eval(".charts .uplot canvas", (c) => c.filter((x) => x.width > 0).length);
    assert(charts === 4, `${charts} charts drawn`);
    // The replay: scrubbing to the end shows another frame (the wire has moved).
    const last = Number(await page.getAttribute("#scrubber", "max"));
    assert(last >= 2, `${last + 1} replay frames`);
    await page.waitForFunction(() => document.querySelector("#replay-frame")?.dataset.index === "0" && document.querySelector("#replay-frame").complete, null, { timeout: 15_000 });
    const first = await blocks(page, "#replay-frame");
    await page.$eval("#scrubber", (s) => {
      s.value = s.max;
      s.dispatchEvent(new Event("input"));
    });
    await page.waitForFunction((n) => document.querySelector("#replay-frame")?.dataset.index === String(n) && document.querySelector("#replay-frame").complete, last, { timeout: 15_000 });
    const end = await blocks(page, "#replay-frame");
    const change = largestChange(first, end);
    console.log(`  scrubbing 0 → ${last}: largest 8×8-block change ${change.toFixed(1)} grey levels; time ${await page.textContent("#replay-time")}`);
    // Replay frames are noise-free: two frames of the same state are identical.
    assert(change > 3, `the frame changed when scrubbing: ${change}`);
    // The CSV export holds the stored scores (the history's, read from the store).
    const [download] = await Promise.all([page.waitForEvent("download"), page.click("#export-csv")]);
    const csv = readFileSync(await download.path(), "utf8");
    const exported = new Map(
      csv.trim().split("\n").slice(1).map((line) => {
        const cells = line.match(/("([^"]|"")*"|[^,]*)(,|$)/g).map((c) => c.replace(/,$/, ""));
        return [cells[0], Number(cells[3])];
      }),
    );
    await page.waitForFunction(() => document.querySelector("#history li.current")?.dataset.metrics, null, { timeout: 10_000 });
    const stored = JSON.parse(await page.getAttribute("#history li.current", "data-metrics"));
    const keys = Object.keys(stored);
    assert(keys.length >= 15 && keys.length === exported.size, `${keys.length} stored, ${exported.size} exported`);
    for (const k of keys) assert(exported.get(k) === stored[k], `${k}: CSV ${exported.get(k)} vs stored ${stored[k]}`);
    // The learning curve has both sessions.
    const points = await page.getAttribute("#chart-curve", "data-points");
    assert(points === "2", `learning curve points: ${points}`);
    assert((await page.$$eval("#history li", (l) => l.length)) === 2, "both sessions listed");
    // The dashboard lists Rita's sessions with their scores and links to their reports.
    await dash.reload();
    await dash.click("#accounts-box summary");
    const rita = await dash.waitForSelector('#accounts li:has-text("Rita Trainee") details', { timeout: 10_000 });
    await rita.evaluate((d) => {
      d.open = true;
    });
    await dash.waitForFunction(() => [...document.querySelectorAll("#accounts li li")].length === 2, null, { timeout: 10_000 });
    const links = await dash.$$eval("#accounts li li a.report-link", (a) => a.map((x) => x.getAttribute("href")));
    assert(links.length === 2 && links.every((l) => l.includes("report.html?session=")), `report links: ${links}`);
    // A report that cannot be shown says why instead of a blank page.
    await page.goto(`${url}/report.html?session=0123456789abcdef0123456789abcdef`);
    await page.waitForSelector("#report-error:not([hidden])", { timeout: 15_000 });
    const error = await page.textContent("#report-error");
    console.log(`  unknown session: ${error}`);
    assert(/NotFound/.test(error) && error.includes("0123456789abcdef"), `the error names the session: ${error}`);
    await ritas.close();
    await teaching.close();
  });

  await test("the_page_shows_reconnecting_when_the_server_goes", async () => {
    await trainee.waitForSelector('#connection[data-status="connected"]', { timeout: 5_000 });
    server.stdin.end();
    await trainee.waitForSelector('#connection[data-status="reconnecting"]', { timeout: 15_000 });
    // The server shut down cleanly although browsers held streams open.
    const code = await new Promise((r) => (server.exitCode !== null ? r(server.exitCode) : server.on("exit", r)));
    assert(code === 0, `server exit status ${code}`);
  });

  await test("after_a_server_restart_the_page_says_the_session_ended", async () => {
    // The same address and database: the page reconnects, and the server no longer has the
    // session, so the page stops retrying and says so.
    ({ child: server } = await startServer(dir, new URL(url).host));
    await trainee.waitForSelector('#connection[data-status="ended"]', { timeout: 30_000 });
    const message = await trainee.textContent("#message");
    console.log(`  ${message}`);
    assert(/session has ended/.test(message), `the page says the session ended: ${message}`);
    assert(await trainee.isVisible("#new-session"), "a link to start a new session");
    assert(await trainee.$eval("#reset", (b) => b.disabled), "the controls are disabled");
    // The dashboard lists the ended session among the recorded ones (the key is kept
    // in the instructor's browser storage, not in the address).
    const dashboard = await instructor.newPage();
    dashboard.on("pageerror", (e) => pageErrors.push(`dashboard after restart: ${e.message}`));
    await dashboard.goto(`${url}/dashboard.html`);
    const row = `#recorded li[data-session="${sessionId}"]`;
    await dashboard.waitForSelector(row, { timeout: 15_000 });
    const text = await dashboard.textContent(row);
    console.log(`  recorded: ${text}`);
    // A clean shutdown closes its sessions (a crash would leave them "interrupted").
    assert(/closed|interrupted/.test(text) && text.includes("e2e-trainee"), `the ended session listed: ${text}`);
  });

  await test("no_script_errors_on_any_page", async () => {
    assert(pageErrors.length === 0, pageErrors.join("\n"));
  });
} finally {
  await browser.close();
  server.stdin.end();
  server.kill();
  rmSync(dir, { recursive: true, force: true });
}
const failed = results.filter((r) => !r.ok).length;
console.log(`test result: ${failed ? "FAILED" : "ok"}. ${results.length - failed} passed; ${failed} failed; screenshots in ${artifacts}`);
process.exit(failed ? 1 : 0);
