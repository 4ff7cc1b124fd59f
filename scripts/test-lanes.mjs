// Runs the workspace's test binaries in two lanes at once, after one `cargo test --no-run`
// build (arguments are passed to it). Lane 1: the server's end-to-end tests (package
// cathlab-app: real-time sessions, browsers and timeouts, mostly waiting) at normal priority.
// Lane 2: every other binary (CPU-bound physics, imaging and rendering) under `nice -n 19`,
// so it takes only the CPU lane 1 leaves idle and never slows a real-time session. Each
// binary's output is printed whole when it ends, headed as cargo heads it; the exit status
// is non-zero if any binary failed.
import { execFileSync, spawn } from "node:child_process";
import { dirname, basename } from "node:path";

const args = process.argv.slice(2);
const out = execFileSync(
  "cargo",
  ["test", "--no-run", "--message-format=json-render-diagnostics", ...args],
  { maxBuffer: 1 << 30, stdio: ["ignore", "pipe", "inherit"] },
).toString();

const binaries = [];
for (const line of out.split("\n")) {
  if (!line.startsWith("{")) continue;
  const m = JSON.parse(line);
  if (m.reason !== "compiler-artifact" || !m.executable || !m.profile?.test) continue;
  binaries.push({
    path: m.executable,
    cwd: dirname(m.manifest_path),
    package: m.package_id,
    name: `${m.target.kind.join(",")} ${m.target.name} (${basename(m.executable)})`,
  });
}
const isServer = (b) => /[/#]cathlab-app[@#]|\/server\/app#/.test(b.package) || b.cwd.endsWith("/server/app");
const lanes = [binaries.filter(isServer), binaries.filter((b) => !isServer(b))];

function run(b, nice) {
  return new Promise((resolve) => {
    const started = Date.now();
    const [cmd, argv] = nice ? ["nice", ["-n", "19", b.path]] : [b.path, []];
    const child = spawn(cmd, argv, { cwd: b.cwd, stdio: ["ignore", "pipe", "pipe"] });
    const chunks = [];
    child.stdout.on("data", (d) => chunks.push(d));
    child.stderr.on("data", (d) => chunks.push(d));
    child.on("close", (code, signal) => {
      const s = ((Date.now() - started) / 1000).toFixed(1);
      process.stdout.write(`     Running ${b.name} [lane ${nice ? 2 : 1}, ${s} s]\n`);
      process.stdout.write(Buffer.concat(chunks));
      if (code !== 0) process.stdout.write(`error: ${b.name} failed (${signal ?? `exit ${code}`})\n`);
      resolve(code === 0);
    });
  });
}

async function lane(list, nice) {
  let ok = true;
  for (const b of list) ok = (await run(b, nice)) && ok;
  return ok;
}

const started = Date.now();
const results = await Promise.all([lane(lanes[0], false), lane(lanes[1], true)]);
console.log(
  `test lanes: ${binaries.length} binaries (${lanes[0].length} server, ${lanes[1].length} other) in ${((Date.now() - started) / 1000).toFixed(0)} s`,
);
process.exit(results.every(Boolean) ? 0 : 1);
