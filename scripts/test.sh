#!/usr/bin/env bash
# Every test: formatting, lints, the whole workspace's tests including the benchmarks' smoke
# runs (optimised test profile), the web client's generated-code check, type check and unit
# tests, and its browser tests in headless Chromium (run by cargo test, against the real
# server). Ends with a one-line total.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
# CI has lavapipe (installed by setup.sh): the wgpu tests must run, not skip.
export CATHLAB_REQUIRE_GPU="${CATHLAB_REQUIRE_GPU:-1}"
# Each stage's heading says how long the run has taken so far.
phase() { echo "== $* [at $((SECONDS / 60)) min $((SECONDS % 60)) s]"; }
# A build from scratch: incremental compilation would only add its bookkeeping.
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
# The web client's packages, Chromium and PostgreSQL come over the network while the compiler
# works (they take little CPU): started now, waited for before the web client's checks.
prepare_log=$(mktemp)
(build_web_client && install_test_packages) >"$prepare_log" 2>&1 &
prepare=$!
phase "cargo fmt --check"
cargo fmt --all --check
phase "cargo clippy"
cargo clippy --locked --workspace --all-targets -- -D warnings
phase "cargo doc (warnings are errors)"
RUSTDOCFLAGS="-D warnings" cargo doc --locked --workspace --no-deps
log=$(mktemp)
trap 'rm -f "$log"' EXIT
phase "web client: install, generated code current, build, unit tests"
prepare_status=0
wait "$prepare" || prepare_status=$?
cat "$prepare_log"
rm -f "$prepare_log"
[ "$prepare_status" = 0 ] || { echo "installing the web client or the test packages failed"; exit 1; }
(
  cd client-web
  npm run --silent check-generated
  npx vitest run --reporter=default --reporter=json --outputFile=test-results/vitest.json
  node -e 'const r = require("./test-results/vitest.json");
    console.log(`test result: ${r.success ? "ok" : "FAILED"}. ${r.numPassedTests} passed; ${r.numFailedTests} failed (vitest)`);
    process.exit(r.success ? 0 : 1)'
) 2>&1 | tee -a "$log"
phase "cargo test (lib, bins, tests, benches in test mode; the browser tests among them; scripts/run-tests.sh)"
export CATHLAB_REQUIRE_BROWSER=1
bash scripts/run-tests.sh 2>&1 | tee -a "$log"
awk '/^test result:/ { p += $4; f += $6 } END { printf "cathlab: %d passed, %d failed\n", p, f }' "$log"
phase "done"
