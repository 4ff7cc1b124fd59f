#!/usr/bin/env bash
# The main job. Until the server exists (issue 7) it runs the physics demo.
set -euo pipefail
cd "$(dirname "$0")/.."
source scripts/setup.sh
exec cargo run --release --locked -p cathlab-physics --bin cathlab-demo "$@"
