#!/usr/bin/env bash
# Every test: formatting, lints, and the whole workspace's tests (optimised test profile).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
echo "== cargo fmt --check"
cargo fmt --all --check
echo "== cargo clippy"
cargo clippy --locked --workspace --all-targets -- -D warnings
echo "== cargo test"
cargo test --locked --workspace --all-targets
echo "== benchmarks compile and run once (smoke)"
cargo test --locked -p cathlab-physics --benches
