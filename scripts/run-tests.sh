#!/usr/bin/env bash
# Runs every test of the workspace as `cargo test --workspace --all-targets` would (lib, bins,
# tests, benches in test mode; the examples are left to clippy) in two lanes at once, and
# prints each binary's output whole when it ends, then a table of the ten slowest binaries, so
# a regression is seen the day it lands.
#
# - The timed lane, one binary at a time at normal priority: the binaries that start the
#   server or a real-time session, or assert something about time (missed steps, real-time
#   pushes, the haptic loop, the soak and load smoke runs, a bomb refused within seconds).
# - The compute lane, TEST_JOBS binaries at a time (default 3), longest first, each in a
#   scheduler autogroup of its own at the lowest priority (`setsid`, nice 19): everything
#   else (pure computation, no clock in any assertion). It takes the cycles the timed lane
#   leaves: on the 2-core reference machine the timed binaries keep about one core busy (a
#   server waited on in real time, a browser).
#
# On the 2-core machine the compute lane alone took 260 s two at a time and 400 s one at a
# time (each binary's test harness runs two threads, but most binaries end on one long test),
# and the timed lane run after it another ~400 s; side by side, from a fresh clone, they take
# 535-661 s, about the CPU time of the whole (970-1,180 s) over two cores. Two or three
# compute binaries at a time made no difference (661 and 659 s).
#
#   scripts/run-tests.sh            (TEST_JOBS compute binaries at once, default 3)
#   TEST_ONLY='^physics/' scripts/run-tests.sh   only the binaries whose name matches (grep -E)
#
# Exit status 1 when any binary fails; the failing ones are named at the end.
set -euo pipefail
cd "$(dirname "$0")/.."
jobs="${TEST_JOBS:-3}"
# The timed lane, in this order (the longest first; the rest of tests/ after them).
timed="tests/web_client tests/attack tests/soak_smoke tests/thrombectomy tests/deployment
  tests/haptic_bridge tests/load_smoke tests/server tests/assessment tests/haptic_latency(bench)
  engine/world engine/cathlab_engine(lib) app/cathlab_app(lib) agones/cathlab_agones(lib)
  client-haptic/cathlab_haptic_bridge(lib) imaging/bombs"
timed=" $(echo $timed) "
# The compute lane's longest binaries (wall seconds on the reference machine), started first
# so that none of them ends the run alone; the others follow in cargo's order.
longest="imaging/segment engine/cases engine/scenes physics/coaxial anatomy/decimate
  imaging/surface_centerlines xray/frame(bench) engine/surface_scene xray/golden
  anatomy/surface engine/segmented_scene engine/report imaging/circle_of_willis
  engine/iliac(bench) imaging/segment(bench) anatomy/cathlab_anatomy(lib)"
longest=" $(echo $longest) "

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT

echo "-- building every test binary and the binaries the end-to-end suites run"
# One build of every target with the test profile: the binaries then share the test
# binaries' dependency features (a separate `cargo build -p` would resolve features anew and
# compile part of the tree twice).
# Not the examples: nothing here runs them, and `cargo clippy --all-targets` compiles them.
cargo build --locked --profile test --workspace --lib --bins --tests --benches \
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
# The lanes' lists: the timed lane in its order, the compute lane longest first.
: >"$work/timed.tsv"
: >"$work/compute.tsv"
for want in $timed; do
  awk -F'\t' -v n="$want" '$1 == n' "$work/list.tsv" >>"$work/timed.tsv"
done
for want in $longest; do
  awk -F'\t' -v n="$want" '$1 == n' "$work/list.tsv" >>"$work/compute.tsv"
done
awk -F'\t' -v t="$timed" -v l="$longest" \
  'index(t, " " $1 " ") == 0 && index(l, " " $1 " ") == 0' "$work/list.tsv" >>"$work/compute.tsv"
echo "-- $(wc -l <"$work/list.tsv") test binaries: $(wc -l <"$work/timed.tsv") in the timed lane one at a time," \
  "$(wc -l <"$work/compute.tsv") in the compute lane $jobs at a time (niced)"

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

run_one() { # name dir executable [nice]
  local name="$1" dir="$2" exe="$3" niced="${4:-}" start rc=0 k
  k=$(key "$name")
  start=$EPOCHREALTIME
  # The binary's own status (pipefail is on), not stamp's; `times` gives the CPU seconds the
  # binary and the processes it waited for (servers, browsers) used.
  (
    cd "$dir" || exit 1
    status=0
    if [ -n "$niced" ]; then
      # Its own session, hence its own scheduler autogroup, at the autogroup's lowest
      # priority: per-process nice acts only within an autogroup, and the browser's
      # processes start their own (measured: the browser tests took twice as long beside
      # per-process niced work, and as long as alone beside a niced autogroup).
      setsid --wait bash -c 'echo 19 >/proc/self/autogroup 2>/dev/null; exec nice -n 19 "$0"' "$exe" \
        2>&1 | stamp "$start" || status=$?
    else
      "$exe" 2>&1 | stamp "$start" || status=$?
    fi
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

report_finished() {
  for f in "$work"/done.*; do
    case "$f" in *.tmp) continue ;; esac
    [ -e "$f" ] && report "${f#"$work"/done.}"
  done
  return 0
}

started=$SECONDS
# The timed lane: one binary after another, in the background of this shell.
(
  while IFS=$'\t' read -r name dir exe; do
    run_one "$name" "$dir" "$exe"
  done <"$work/timed.tsv"
) &

# The compute lane: $jobs binaries at a time (their process ids in `running`).
running=()
while IFS=$'\t' read -r name dir exe; do
  while :; do
    report_finished
    alive=()
    for pid in "${running[@]}"; do
      kill -0 "$pid" 2>/dev/null && alive+=("$pid")
    done
    running=("${alive[@]}")
    [ "${#running[@]}" -lt "$jobs" ] && break
    sleep 0.2
  done
  run_one "$name" "$dir" "$exe" nice &
  running+=($!)
done <"$work/compute.tsv"
while [ "$(jobs -rp | wc -l)" -gt 0 ]; do
  report_finished
  sleep 0.2
done
wait
report_finished

echo "-- the ten slowest test binaries (wall and CPU seconds; the timed lane one at a time beside the compute lane's $jobs, niced)"
sort -rn "$work/times" | head -10 | awk '{ printf "  %8.1f s  %8.1f s CPU  %s\n", $1, $2, $3 }'
awk -v e=$((SECONDS - started)) '{ w += $1; c += $2 }
  END { printf "-- all %d binaries: %.0f s wall, %.0f s CPU; both lanes done in %d s\n", NR, w, c, e }' "$work/times"
if [ -s "$work/failed" ]; then
  echo "-- FAILED: $(tr '\n' ' ' <"$work/failed")"
  exit 1
fi
