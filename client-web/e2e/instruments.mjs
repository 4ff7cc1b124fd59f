// Scenes with several instruments: two hands on the coaxial scene (stack panel, observer,
// exchange), the stroke scene's thrombectomy panel, and loading and unloading from access.
import { join } from "node:path";
import { KEY, artifacts, assert } from "./harness.mjs";
import { connected, nextFrame, outOfView } from "./page.mjs";

export async function twoHands(ctx) {
  const { browser, pageErrors, url } = ctx;
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
}

export async function strokeScene(ctx) {
  const { browser, pageErrors, url } = ctx;
  const machine = await browser.newContext({ viewport: { width: 1280, height: 800 } });
  const page = await machine.newPage();
  page.on("pageerror", (e) => pageErrors.push(`stroke: ${e.message}`));
  const message = () => page.textContent("#message");
  // The stroke scene (its anatomy takes a while to build on first use).
  await page.goto(`${url}/?label=e2e-stroke&scene=stroke_m1_thrombectomy`);
  await connected(page, 240_000);
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
}

export async function accessScene(ctx) {
  const { browser, pageErrors, url } = ctx;
  const machine = await browser.newContext({ viewport: { width: 1280, height: 800 } });
  const page = await machine.newPage();
  page.on("pageerror", (e) => pageErrors.push(`access: ${e.message}`));
  const count = () => page.evaluate(() => document.querySelectorAll("#stack li").length);
  await page.goto(`${url}/?label=e2e-access&scene=stroke_m1_from_access`);
  await connected(page, 240_000);
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
}
