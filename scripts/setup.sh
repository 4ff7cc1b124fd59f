#!/usr/bin/env bash
# Set-up shared by the run and test commands: checks the Rust toolchain (the only thing the
# physics stage needs) and installs rustfmt/clippy if missing. Later stages add their system
# packages here (software Vulkan, Chromium).
set -euo pipefail
if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    export PATH="$HOME/.cargo/bin:$PATH"
  else
    echo "cathlab needs a Rust toolchain (cargo); install it with rustup" >&2
    exit 1
  fi
fi
if command -v rustup >/dev/null 2>&1; then
  rustup component list --installed 2>/dev/null | grep -q '^rustfmt' || rustup component add rustfmt
  rustup component list --installed 2>/dev/null | grep -q '^clippy' || rustup component add clippy
fi
