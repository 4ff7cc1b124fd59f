#!/usr/bin/env bash
# The main job: builds the web client and cathlab-server, and runs the server on
# 127.0.0.1:50051 with the scenes in scenes/ (default: arch_to_cow_lcca), an embedded SQLite
# store in var/, built anatomies kept in var/asset-cache (the neuro phantom's: ~30 s to build,
# seconds to read back after a restart), and the web client at the printed URL (trainee view
# at /, instructor dashboard at /dashboard.html). Extra arguments go to the server (see
# `cathlab-server --help`), e.g. `scripts/run.sh --listen 0.0.0.0:50051`.
# The instructor key comes from CATHLAB_INSTRUCTOR_KEY (default here: "instructor", which the
# server accepts on 127.0.0.1 only: to listen beyond it, export a random key of 16+ characters).
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
export CATHLAB_INSTRUCTOR_KEY="${CATHLAB_INSTRUCTOR_KEY:-instructor}"
build_web_client
cargo build --release --locked -p cathlab-app --bin cathlab-server
exec target/release/cathlab-server --scenes scenes --database var/cathlab.sqlite \
  --asset-disk-cache var/asset-cache --web-root client-web/dist "$@"
