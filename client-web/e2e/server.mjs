// The cathlab-server process: starting it (and again on the same address and database),
// and the checks of the pages while it goes away and comes back.
import { spawn } from "node:child_process";
import { writeFileSync } from "node:fs";
import { join } from "node:path";
import { createInterface } from "node:readline";
import { KEY, assert, here, repo, serverBinary } from "./harness.mjs";

/** Starts the server on a free port; resolves with its base URL once it listens. */
export function startServer(dir, listen = "127.0.0.1:0") {
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

export async function pageShowsReconnecting(ctx) {
  const { server, trainee } = ctx;
  await trainee.waitForSelector('#connection[data-status="connected"]', { timeout: 5_000 });
  server.stdin.end();
  await trainee.waitForSelector('#connection[data-status="reconnecting"]', { timeout: 15_000 });
  // The server shut down cleanly although browsers held streams open.
  const code = await new Promise((r) => (server.exitCode !== null ? r(server.exitCode) : server.on("exit", r)));
  assert(code === 0, `server exit status ${code}`);
}

export async function sessionEndedAfterARestart(ctx) {
  const { instructor, pageErrors, sessionId, trainee, url } = ctx;
  // The same address and database: the page reconnects, and the server no longer has the
  // session, so the page stops retrying and says so.
  ({ child: ctx.server } = await startServer(ctx.dir, new URL(url).host));
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
}
