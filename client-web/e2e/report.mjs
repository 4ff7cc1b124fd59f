// The session report: a trainee account finishes two sessions and reads the report, its
// replay, CSV export and learning curve; the dashboard lists both; an unknown session's error.
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { KEY, artifacts, assert } from "./harness.mjs";
import { blocks, largestChange } from "./page.mjs";

export async function twoSessionsAndTheReport(ctx) {
  const { browser, pageErrors, url } = ctx;
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
    await page.waitForSelector("#report-link", { timeout: 30_000 });
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
}
