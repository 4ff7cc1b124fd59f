// The instructor's side: the dashboard's card for a live session, the read-only observer
// view, and an assessment session started from the dashboard.
import { join } from "node:path";
import { KEY, artifacts, assert } from "./harness.mjs";
import { millimetres, nextFrame } from "./page.mjs";

export async function dashboardListsTheSession(ctx) {
  const { instructor, pageErrors, sessionId, trainee, url } = ctx;
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
  const observer = await instructor.newPage();
  ctx.observer = observer;
  observer.on("pageerror", (e) => pageErrors.push(`observer: ${e.message}`));
  await observer.goto(href);
  await trainee.bringToFront();
  await trainee.keyboard.up("f");
}

export async function observerCannotCommand(ctx) {
  const { observer, trainee } = ctx;
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
}

export async function assessmentWithoutGuidance(ctx) {
  const { browser, pageErrors, url } = ctx;
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
}
