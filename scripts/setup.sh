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
# Installs Debian packages; needs root (CI runs as root) or passwordless sudo.
apt_install() {
  local sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  export DEBIAN_FRONTEND=noninteractive
  # One package-list update per run.
  if [ -z "${CATHLAB_APT_UPDATED:-}" ]; then
    $sudo apt-get update -qq
    CATHLAB_APT_UPDATED=1
  fi
  $sudo apt-get install -y -qq --no-install-recommends "$@" >/dev/null
}
# Software Vulkan (lavapipe) for the wgpu renderer: Debian's mesa-vulkan-drivers and the
# Vulkan loader. Installed once.
if [ ! -f /usr/share/vulkan/icd.d/lvp_icd.x86_64.json ]; then
  apt_install mesa-vulkan-drivers libvulkan1
fi
# Pin wgpu to lavapipe (NOTES.md): one adapter, the same everywhere.
export VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
# Mesa's window-system code wants a runtime directory even off-screen.
if [ -z "${XDG_RUNTIME_DIR:-}" ]; then
  export XDG_RUNTIME_DIR="${TMPDIR:-/tmp}/cathlab-runtime-$(id -u)"
  mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
fi
# Node.js and npm for the web client (the machine's own, else Debian's).
if ! command -v npm >/dev/null 2>&1; then
  apt_install nodejs npm
fi

# Builds the web client into client-web/dist (installs the lockfile's versions when
# node_modules is missing or older than the lockfile). cathlab-server serves it. Not `npm ci`:
# npm leaves @bufbuild/buf's other-platform binaries out of the lockfile, and `npm ci` then
# refuses it as out of sync; `npm install --no-save` installs the same locked versions and
# never rewrites the lockfile.
build_web_client() {
  (
    cd client-web
    if [ ! -d node_modules ] || [ package-lock.json -nt node_modules/.package-lock.json ]; then
      npm install --no-save --no-audit --no-fund --loglevel=error
    fi
    npm run --silent build
  )
}

# The test command's packages: Debian's Chromium for the browser tests, and Debian's
# PostgreSQL server for the PostgreSQL and fleet tests (they make throwaway clusters of their
# own on free ports; the package's default cluster is not started). One install for both.
install_test_packages() {
  local missing=()
  [ -x /usr/bin/chromium ] || missing+=(chromium fonts-dejavu-core)
  compgen -G "/usr/lib/postgresql/*/bin/initdb" >/dev/null || missing+=(postgresql)
  if [ ${#missing[@]} -gt 0 ]; then
    apt_install "${missing[@]}"
  fi
}
