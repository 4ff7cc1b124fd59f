#!/usr/bin/env bash
# The main job: builds and runs cathlab-server on 127.0.0.1:50051 with the scenes in scenes/
# (default: arch_to_cow_lcca) and an embedded SQLite store in var/. Extra arguments go to the
# server (see `cathlab-server --help`), e.g. `scripts/run.sh --listen 0.0.0.0:50051`.
# The instructor key comes from CATHLAB_INSTRUCTOR_KEY (default here: "instructor").
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
export CATHLAB_INSTRUCTOR_KEY="${CATHLAB_INSTRUCTOR_KEY:-instructor}"
cargo build --release --locked -p cathlab-app --bin cathlab-server
exec target/release/cathlab-server --scenes scenes --database var/cathlab.sqlite "$@"
