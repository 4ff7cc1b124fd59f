// The command line and the test runner: paths and options, the instructor key the server is
// started with, assert, and test() with its results (one `test NAME ... ok` line each).
import { mkdirSync } from "node:fs";
import { join, resolve } from "node:path";

export const here = new URL("..", import.meta.url).pathname;
export const repo = resolve(here, "..");
const arg = (name, fallback) => {
  const i = process.argv.indexOf(name);
  return i >= 0 ? process.argv[i + 1] : fallback;
};
export const serverBinary = resolve(arg("--server", process.env.CATHLAB_SERVER ?? join(repo, "target/debug/cathlab-server")));
export const chromiumPath = arg("--chromium", process.env.CHROMIUM ?? "/usr/bin/chromium");
const only = arg("--only", undefined);
export const artifacts = join(here, "test-results");
mkdirSync(artifacts, { recursive: true });
export const KEY = "e2e-instructor-key";

export const assert = (condition, message) => {
  if (!condition) throw new Error(message);
};

export const results = [];
export async function test(name, body) {
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
