// Checks that src/gen is what `buf generate` makes from ../proto now: generates into a
// temporary directory and compares file by file. Exits 1 naming the stale files.
import { execFileSync } from "node:child_process";
import { mkdtempSync, readdirSync, readFileSync, rmSync, statSync } from "node:fs";
import { tmpdir } from "node:os";
import { join, relative } from "node:path";

const root = new URL("..", import.meta.url).pathname;
const out = mkdtempSync(join(tmpdir(), "cathlab-gen-"));
const files = (dir) =>
  readdirSync(dir).flatMap((name) => {
    const path = join(dir, name);
    return statSync(path).isDirectory() ? files(path) : [path];
  });
try {
  execFileSync(
    join(root, "node_modules/.bin/buf"),
    ["generate", "../proto", "--template", "buf.gen.yaml", "--output", out],
    {
      cwd: root,
      stdio: "inherit",
      env: { ...process.env, PATH: `${join(root, "node_modules/.bin")}:${process.env.PATH}` },
    },
  );
  const fresh = new Map(files(join(out, "src/gen")).map((f) => [relative(join(out, "src/gen"), f), f]));
  const committed = new Map(files(join(root, "src/gen")).map((f) => [relative(join(root, "src/gen"), f), f]));
  const stale = [];
  for (const [name, path] of fresh) {
    if (!committed.has(name) || readFileSync(path, "utf8") !== readFileSync(committed.get(name), "utf8")) {
      stale.push(name);
    }
  }
  for (const name of committed.keys()) if (!fresh.has(name)) stale.push(`${name} (no longer generated)`);
  if (stale.length > 0) {
    console.error(`client-web/src/gen is stale (run \`npm run generate\` in client-web): ${stale.join(", ")}`);
    process.exit(1);
  }
  console.log(`client-web/src/gen is current (${fresh.size} file(s) from ../proto)`);
} finally {
  rmSync(out, { recursive: true, force: true });
}
