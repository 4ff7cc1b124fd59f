#!/usr/bin/env bash
# Every test: formatting, lints, and the whole workspace's tests including the benchmarks'
# smoke runs (optimised test profile). Ends with a one-line total.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
# CI has lavapipe (installed by setup.sh): the wgpu tests must run, not skip.
export CATHLAB_REQUIRE_GPU="${CATHLAB_REQUIRE_GPU:-1}"
echo "== cargo fmt --check"
cargo fmt --all --check
echo "== cargo clippy"
cargo clippy --locked --workspace --all-targets -- -D warnings
echo "== cargo test (lib, bins, tests, benches in test mode)"
log=$(mktemp)
trap 'rm -f "$log"' EXIT
cargo test --locked --workspace --all-targets 2>&1 | tee "$log"
awk '/^test result:/ { p += $4; f += $6 } END { printf "cathlab: %d passed, %d failed\n", p, f }' "$log"
