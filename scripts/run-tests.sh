#!/usr/bin/env bash
# Runs every test of the workspace as `cargo test --workspace --all-targets` would (lib, bins,
# tests, benches in test mode), TEST_JOBS binaries at a time, and those that measure time
# (missed steps, real-time pushes, the haptic loop, the soak and load smoke runs) afterwards,
# each alone. Prints each binary's output whole when it ends, then a table of the ten slowest
# binaries, so a regression is seen the day it lands.
#
# TEST_JOBS defaults to 1: on the 2-core reference machine three at a time made the whole
# run slower, not faster (engine/scenes 190 → 453 s, tests/thrombectomy 103 → 1,308 s: the
# CPU-bound binaries share two cores, and the end-to-end server under load runs behind
# real time). Larger machines may set it higher. The binaries named in `light` below keep
# about one core busy or less (one long single-threaded test, or a server waited on in real
# time, with no assertion about time): after the others they run 2 × TEST_JOBS at a time,
# longest first (the 2-core machine's run: 282 s of them one at a time).
#
#   scripts/run-tests.sh            (TEST_JOBS binaries at once, default 1)
#   TEST_ONLY='^physics/' scripts/run-tests.sh   only the binaries whose name matches (grep -E)
#
# Exit status 1 when any binary fails; the failing ones are named at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs="${TEST_JOBS:-1}"
# Test binaries whose assertions are about time: run alone, after the others.
alone=" tests/attack tests/haptic_bridge tests/haptic_latency(bench) tests/load_smoke tests/soak_smoke tests/web_client "
# Binaries that use about one core or less and assert nothing about time, longest first
# (their wall seconds alone on the 2-core machine): run two at a time after the others.
light="tests/deployment tests/thrombectomy imaging/surface_centerlines tests/server
  physics/coaxial(bench) engine/stress(bench) xray/frame(bench) engine/surface_scene
  xray/golden engine/segmented_scene engine/iliac(bench) imaging/segment(bench)
  tests/assessment physics/substructure physics/charts(bench)"
light=" $(echo $light) "

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

echo "-- building every test binary and the binaries the end-to-end suites run"
# One build of every target with the test profile: the binaries then share the test
# binaries' dependency features (a separate `cargo build -p` would resolve features anew and
# compile part of the tree twice).
cargo build --locked --profile test --workspace --all-targets \
  --message-format=json-render-diagnostics >"$work/artifacts.json"
# The suites in tests/ find the binaries just built (cathlab_tests::binary).
export CATHLAB_TESTS_PREBUILT=1

# One line per test executable: name (package folder/target)<TAB>package folder<TAB>executable.
node -e '
  const lines = require("fs").readFileSync(process.argv[1], "utf8").split("\n");
  const seen = new Set();
  for (const line of lines) {
    if (!line.startsWith("{")) continue;
    const m = JSON.parse(line);
    if (m.reason !== "compiler-artifact" || !m.executable || !m.profile.test) continue;
    if (m.target.kind.includes("example")) continue;
    if (seen.has(m.executable)) continue;
    seen.add(m.executable);
    const kind = m.target.kind.includes("lib") ? "lib" : m.target.kind[0];
    const dir = require("path").dirname(m.manifest_path);
    // A bench and a test may share a name: the kind tells them apart.
    const target = kind === "test" ? m.target.name : `${m.target.name}(${kind})`;
    const name = `${require("path").basename(dir)}/${target}`;
    console.log([name, dir, m.executable].join("\t"));
  }' "$work/artifacts.json" | grep -E -- "${TEST_ONLY:-.}" >"$work/list.tsv" || true
echo "-- $(wc -l <"$work/list.tsv") test binaries, $jobs at a time, the light ones $((2 * jobs)) at a time, then those that measure time alone"

key() { echo "${1//\//__}"; } # a file name for a binary's name

# Copies its input, each test's result line ("test x ... ok") prefixed with the seconds since
# the binary started, so that a slow test is seen by name.
stamp() { # start (EPOCHREALTIME)
  local start=${1/./} line tenths
  while IFS= read -r line; do
    case "$line" in
      "test "*" ... "*)
        tenths=$(((${EPOCHREALTIME/./} - start) / 100000))
        printf '[%5d.%d s] %s\n' $((tenths / 10)) $((tenths % 10)) "$line"
        ;;
      *) printf '%s\n' "$line" ;;
    esac
  done
}

run_one() { # name dir executable
  local name="$1" dir="$2" exe="$3" start rc=0 k
  k=$(key "$name")
  start=$EPOCHREALTIME
  # The binary's own status (pipefail is on), not stamp's; `times` gives the CPU seconds the
  # binary and the processes it waited for (servers, browsers) used.
  (
    cd "$dir" || exit 1
    status=0
    "$exe" 2>&1 | stamp "$start" || status=$?
    # (Not piped: a pipeline's `times` would run in a subshell that waited for nothing.)
    times >"$work/cpu.$k"
    awk 'NR == 2 { print cpu($1) + cpu($2) }
      function cpu(t) { split(t, p, /[ms]/); return p[1] * 60 + p[2] }' "$work/cpu.$k" \
      >"$work/cpu.$k.s" && mv "$work/cpu.$k.s" "$work/cpu.$k"
    exit "$status"
  ) >"$work/out.$k" 2>&1 || rc=$?
  echo "$name $rc $(awk -v a="$start" -v b="$EPOCHREALTIME" 'BEGIN { print b - a }')" \
    "$(cat "$work/cpu.$k" 2>/dev/null || echo 0)" >"$work/done.$k.tmp"
  mv "$work/done.$k.tmp" "$work/done.$k"
}

report() { # key
  local k="$1" name rc secs cpu
  read -r name rc secs cpu <"$work/done.$k"
  echo "== $name: $(printf '%.1f s, %.1f s CPU' "$secs" "$cpu")$([ "$rc" = 0 ] || echo ", FAILED (exit $rc)")"
  cat "$work/out.$k"
  echo "$secs $cpu $name" >>"$work/times"
  [ "$rc" = 0 ] || echo "$name" >>"$work/failed"
  rm -f "$work/done.$k" "$work/out.$k" "$work/cpu.$k"
}

wait_for_slot() { # reports every finished binary; returns when fewer than $1 run
  while :; do
    for f in "$work"/done.*; do
      case "$f" in *.tmp) continue ;; esac
      [ -e "$f" ] && report "${f#"$work"/done.}"
    done
    [ "$(jobs -rp | wc -l)" -lt "$1" ] && break
    sleep 0.2
  done
}

while IFS=$'\t' read -r name dir exe; do
  case "$alone$light" in *" $name "*) continue ;; esac
  wait_for_slot "$jobs"
  run_one "$name" "$dir" "$exe" &
done <"$work/list.tsv"
wait
wait_for_slot 1
for want in $light; do
  while IFS=$'\t' read -r name dir exe; do
    [ "$name" = "$want" ] || continue
    wait_for_slot $((2 * jobs))
    run_one "$name" "$dir" "$exe" &
  done <"$work/list.tsv"
done
wait
wait_for_slot 1
while IFS=$'\t' read -r name dir exe; do
  case "$alone" in *" $name "*) ;; *) continue ;; esac
  run_one "$name" "$dir" "$exe"
  report "$(key "$name")"
done <"$work/list.tsv"

echo "-- the ten slowest test binaries (wall and CPU seconds; the first group ran $jobs at a time, the light ones $((2 * jobs)))"
sort -rn "$work/times" | head -10 | awk '{ printf "  %8.1f s  %8.1f s CPU  %s\n", $1, $2, $3 }'
awk '{ w += $1; c += $2 } END { printf "-- all %d binaries: %.0f s wall, %.0f s CPU\n", NR, w, c }' "$work/times"
if [ -s "$work/failed" ]; then
  echo "-- FAILED: $(tr '\n' ' ' <"$work/failed")"
  exit 1
fi
