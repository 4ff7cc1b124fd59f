#!/usr/bin/env bash
# Coverage-guided fuzzing of every file reader (fuzz/, one libFuzzer target per format) on
# stable Rust: libfuzzer-sys built with LLVM's SanitizerCoverage flags, which rustc accepts on
# stable (no cargo-fuzz, no nightly, no sanitizer). See fuzz/README.md.
#
#   scripts/fuzz.sh smoke              the regressions, then every target for
#                                      FUZZ_SMOKE_SECONDS (5) each: about a minute, for CI
#   scripts/fuzz.sh release [SECONDS]  the regressions, then every target for SECONDS (default
#                                      and least 120) each, going on past a crash so that every
#                                      crash is kept: before a release
#   scripts/fuzz.sh regress            replays fuzz/regressions/<target>/ and fuzz/artifacts/<target>/
#   scripts/fuzz.sh check              runs each seed corpus once, printing what each seed parsed to
#   scripts/fuzz.sh build              builds the targets only
#
# Every run: -rss_limit_mb=1024 -malloc_limit_mb=1024 -timeout=10; without a sanitizer
# libFuzzer cannot see single allocations, so the targets' own allocator (fuzz/src/lib.rs)
# aborts on an allocation, or live total, over 1 GiB. A crash, out-of-memory or timeout input
# is written to fuzz/artifacts/<target>/ (crash-*, oom-*, timeout-*): commit it (or a
# minimised copy in fuzz/regressions/<target>/) with the fix, and `regress` replays it from
# then on.
#
# Environment: FUZZ_TARGETS="stl obj ..." (a subset), FUZZ_NO_SCENE=1 (skip the scene target
# and the engine's long build), CARGO_TARGET_DIR (default fuzz/target), FUZZ_SMOKE_SECONDS.
# Installs what it needs on a fresh machine (a C++ compiler for libFuzzer's sources) and skips
# what is there.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
fuzz="$root/fuzz"
mode="${1:-smoke}"

all_targets="stl obj ply vtp swc slicer metaimage nifti dicom devices scene"
features=()
if [ -n "${FUZZ_NO_SCENE:-}" ]; then
  all_targets="${all_targets% scene}"
  features=(--no-default-features)
fi
targets="${FUZZ_TARGETS:-$all_targets}"
limits=(-rss_limit_mb=1024 -malloc_limit_mb=1024 -timeout=10)

log() { echo "fuzz: $*"; }

# --- what a fresh machine lacks ----------------------------------------------------------
if ! command -v cargo >/dev/null 2>&1; then
  if [ -x "$HOME/.cargo/bin/cargo" ]; then
    export PATH="$HOME/.cargo/bin:$PATH"
  else
    echo "fuzz: needs a Rust toolchain (cargo); install it with rustup" >&2
    exit 1
  fi
fi
# libfuzzer-sys compiles libFuzzer's C++ sources.
if ! command -v c++ >/dev/null 2>&1 && ! command -v g++ >/dev/null 2>&1; then
  sudo=""
  [ "$(id -u)" -ne 0 ] && sudo="sudo"
  log "installing g++ (libFuzzer's C++ sources)"
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends g++ >/dev/null
fi

host=$(rustc -vV | sed -n 's/^host: //p')
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$fuzz/target}"
bin_dir="$CARGO_TARGET_DIR/$host/release"

build() {
  # The flags cargo-fuzz passes with `--sanitizer none`, all stable: edge coverage with
  # inline 8-bit counters, the PC table, and comparison tracing (which guides the fuzzer
  # through magic numbers and integer checks). `--target` keeps them off build scripts and
  # proc macros.
  local flags="--cfg fuzzing -Cpasses=sancov-module -Cllvm-args=-sanitizer-coverage-level=4"
  flags+=" -Cllvm-args=-sanitizer-coverage-inline-8bit-counters"
  flags+=" -Cllvm-args=-sanitizer-coverage-pc-table"
  flags+=" -Cllvm-args=-sanitizer-coverage-trace-compares"
  local start=$SECONDS
  log "building the targets (release, instrumented) in $CARGO_TARGET_DIR"
  RUSTFLAGS="$flags ${RUSTFLAGS:-}" cargo build --manifest-path "$fuzz/Cargo.toml" \
    --release --target "$host" --bins "${features[@]}"
  log "build took $((SECONDS - start)) s"
}

failures=()

# Replays each regression and artifact file on its own, so that every failing one is named.
regress() {
  local count=0 t f
  for t in $targets; do
    for f in "$fuzz/regressions/$t"/* "$fuzz/artifacts/$t"/*; do
      [ -f "$f" ] || continue
      count=$((count + 1))
      if ! timeout 120 "$bin_dir/$t" "${limits[@]}" "$f" >"$fuzz/work/last.log" 2>&1; then
        log "REGRESSION FAILS: $t ${f#"$root"/}"
        grep -E "panicked|==cathlab-fuzz==|ERROR: libFuzzer|ALARM|out-of-memory" \
          "$fuzz/work/last.log" | head -5 | sed 's/^/    /'
        failures+=("$t: ${f#"$root"/}")
      fi
    done
  done
  log "replayed $count regression file(s)"
}

# fuzz TARGET SECONDS [extra libFuzzer flags]: new inputs go to fuzz/work/<target>/ (not
# committed), the seeds in fuzz/corpus/<target>/ are read only.
fuzz_one() {
  local t=$1 seconds=$2
  shift 2
  mkdir -p "$fuzz/work/$t" "$fuzz/artifacts/$t"
  local before
  before=$(find "$fuzz/artifacts/$t" -type f | wc -l)
  local out="$fuzz/work/$t.log"
  local status=0
  timeout $((seconds + 120)) "$bin_dir/$t" "${limits[@]}" \
    -max_total_time="$seconds" -print_final_stats=1 \
    -dict="$fuzz/dict/$t.dict" -artifact_prefix="$fuzz/artifacts/$t/" "$@" \
    "$fuzz/work/$t" "$fuzz/corpus/$t" >"$out" 2>&1 || status=$?
  local after
  after=$(find "$fuzz/artifacts/$t" -type f | wc -l)
  local execs
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$out" | tail -1)
  local cov
  cov=$(grep -oE 'cov: [0-9]+' "$out" | tail -1 || true)
  if [ "$status" -ne 0 ] || [ "$after" -gt "$before" ]; then
    log "$t: FAILED (exit $status) after ${execs:-?} runs, $((after - before)) new artifact(s):"
    grep -E "panicked|==cathlab-fuzz==|ERROR: libFuzzer|ALARM|out-of-memory|Test unit written" \
      "$out" | head -8 | sed 's/^/    /'
    failures+=("$t: see ${out#"$root"/}")
  else
    log "$t: ok, ${execs:-?} runs in ${seconds} s, ${cov:-cov ?}"
  fi
}

mkdir -p "$fuzz/work"
case "$mode" in
  build)
    build
    ;;
  regress)
    build
    regress
    ;;
  check)
    build
    for t in $targets; do
      log "$t seeds:"
      CATHLAB_FUZZ_VERBOSE=1 "$bin_dir/$t" "${limits[@]}" "$fuzz/corpus/$t"/* 2>&1 |
        sed -n 's/^cathlab-fuzz: /    /p' | sort | uniq -c || failures+=("$t: a seed fails")
    done
    ;;
  smoke)
    build
    regress
    seconds="${FUZZ_SMOKE_SECONDS:-5}"
    start=$SECONDS
    for t in $targets; do
      fuzz_one "$t" "$seconds"
    done
    log "smoke fuzzing took $((SECONDS - start)) s"
    ;;
  release)
    seconds="${2:-120}"
    if [ "$seconds" -lt 120 ]; then
      echo "fuzz: a release run fuzzes each target for at least 120 s" >&2
      exit 2
    fi
    build
    regress
    start=$SECONDS
    for t in $targets; do
      # Fork mode with the ignore flags: a crash is saved and fuzzing goes on, so one known
      # crash does not hide the others.
      fuzz_one "$t" "$seconds" -fork=1 -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1
    done
    log "release fuzzing took $((SECONDS - start)) s"
    ;;
  *)
    echo "usage: scripts/fuzz.sh smoke | release [SECONDS] | regress | check | build" >&2
    exit 2
    ;;
esac

if [ "${#failures[@]}" -gt 0 ]; then
  log "${#failures[@]} failure(s):"
  printf '    %s\n' "${failures[@]}"
  exit 1
fi
log "no crash"
