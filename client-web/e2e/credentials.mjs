// Credentials and origins: links naming another server send it nothing; a link's key or
// account is not kept or used until the person says so.
import { createServer } from "node:http";
import { KEY, assert } from "./harness.mjs";
import { secretsInAddress } from "./page.mjs";

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

// Links that name another server: nothing this browser keeps goes there. Each page is
// opened with an account token and the instructor key in its storage (as the trainee page
// and the dashboard keep them) by a link naming a stand-in on another port.
const ACCOUNT_KEY = "cathlab.account.token";
const INSTRUCTOR_KEY = "cathlab.instructor.key";
const STORED_ACCOUNT = "e2e-stored-account-token-must-not-leave";

export async function anotherServerGetsNothing(ctx) {
  const { browser, pageErrors, url } = ctx;
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
}

export async function linkKeyWaitsForConnect(ctx) {
  const { browser, pageErrors, url } = ctx;
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
}

export async function signInLinkAsksFirst(ctx) {
  const { browser, pageErrors, url } = ctx;
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
}
