#!/usr/bin/env bash
# Builds the fuzz targets with cargo-fuzz (libFuzzer's coverage instrumentation) and runs each for
# SECONDS (argument, else $STRAND_FUZZ_SECONDS, else 60), with the G-code dictionary, from the
# committed seed corpus (corpus/<target>/, read only) plus a working corpus (work/<target>/, kept
# between runs, ignored by git; libFuzzer's output goes to work/<target>.log). Prints executions,
# exec/s, coverage (cov: edges, ft: features) and corpus size per target, and exits non-zero if any
# target crashed (the input is written to artifacts/<target>/).
#
#   fuzz/run.sh [SECONDS]
#   STRAND_FUZZ_TARGETS="gcode_parser"   targets to run (default: both)
#   STRAND_FUZZ_SANITIZER=address        build with AddressSanitizer (default: none; the parser and
#                                        the path engine have no unsafe code, and ASan runs the path
#                                        target 5x slower)
#   STRAND_FUZZ_JOBS=N                   libFuzzer -fork=N, -ignore_crashes: go on after a crash and
#                                        collect them all (exits non-zero if any)
#   STRAND_FUZZ_SEED=N                   libFuzzer -seed=N (default 0: a new random seed each run; CI
#                                        fixes one, so that its verdict does not depend on the draw —
#                                        long local runs are where new inputs are found)
#
# The toolchain is stable. The default build needs no unstable flag; ASan needs -Zsanitizer, which
# RUSTC_BOOTSTRAP=1 lets stable rustc accept.
set -euo pipefail
cd "$(dirname "$0")"
seconds=${1:-${STRAND_FUZZ_SECONDS:-60}}
targets=${STRAND_FUZZ_TARGETS:-gcode_parser gcode_to_path}
sanitizer=${STRAND_FUZZ_SANITIZER:-none}
jobs=${STRAND_FUZZ_JOBS:-0}
seed=${STRAND_FUZZ_SEED:-0}
export RUST_BACKTRACE=0
if [ "$sanitizer" != none ]; then
  export RUSTC_BOOTSTRAP=1
fi

if ! cargo fuzz --version >/dev/null 2>&1; then
  echo "cargo-fuzz not found: cargo install cargo-fuzz --locked" >&2
  exit 1
fi
start=$(date +%s)
if [ "$targets" = "$(cargo fuzz list | xargs)" ]; then
  cargo fuzz build --sanitizer "$sanitizer"
else
  for target in $targets; do
    cargo fuzz build --sanitizer "$sanitizer" "$target"
  done
fi
echo "fuzz: built in $(($(date +%s) - start)) s (sanitizer $sanitizer)"

host=$(rustc -vV | sed -n 's/^host: //p')
failed=()
for target in $targets; do
  bin=target/$host/release/$target
  mkdir -p "work/$target" "artifacts/$target"
  started=$(date +%s)
  log=work/$target.log
  extra=()
  if [ "$jobs" -gt 0 ]; then
    extra=(-fork="$jobs" -ignore_crashes=1 -ignore_timeouts=1 -ignore_ooms=1)
  fi
  set +e
  "$bin" "work/$target" "corpus/$target" -dict=gcode.dict -max_total_time="$seconds" -max_len=8192 -timeout=30 -seed="$seed" \
    -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="artifacts/$target/" "${extra[@]}" > "$log" 2>&1
  rc=$?
  set -e
  # The last status line ("#N DONE cov: .. ft: .. corp: ..", or the last one before a crash) and
  # libFuzzer's final stats.
  status=$(grep -E '^#[0-9]+' "$log" | tail -n 1 || true)
  runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
  rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -n 1)
  [ -n "$runs" ] || runs=$(sed -nE 's/^#([0-9]+).*/\1/p' <<<"$status")
  [ -n "$rate" ] || rate=$(sed -nE 's/.*exec\/s: ([0-9]+).*/\1/p' <<<"$status")
  cov=$(sed -nE 's/.* cov: ([0-9]+).*/\1/p' <<<"$status")
  ft=$(sed -nE 's/.* ft: ([0-9]+).*/\1/p' <<<"$status")
  corp=$(sed -nE 's/.* corp: ([0-9]+(\/[0-9a-zA-Z]+)?).*/\1/p' <<<"$status")
  crashes=$(grep -cE '^(==[0-9]+== ?ERROR|SUMMARY: libFuzzer)' "$log" || true)
  if [ "$jobs" -gt 0 ]; then
    # Fork mode: the status line counts them ("oom/timeout/crash: 0/0/0").
    crashes=$(sed -nE 's/.*oom\/timeout\/crash: ([0-9]+)\/([0-9]+)\/([0-9]+).*/\1 \2 \3/p' <<<"$status" | awk '{ print $1 + $2 + $3 }')
    crashes=${crashes:-0}
  fi
  if [ "$rc" -ne 0 ] || [ "$crashes" -gt 0 ]; then
    echo "---- $target failed (libFuzzer's output: fuzz/$log) ----"
    grep -E -A1 "panicked at" "$log" | grep -v '^--$' | head -n 10 || true
    grep -E "^SUMMARY|ERROR: AddressSanitizer|timeout after|out-of-memory" "$log" | sort | uniq -c | head -n 10 || true
    grep -oE "artifacts/$target/[a-z]+-[0-9a-f]+" "$log" | sort -u | head -n 20 || true
    echo "reproduce: fuzz/$bin ARTIFACT; minimise: (cd fuzz && cargo fuzz tmin $target ARTIFACT)"
    failed+=("$target")
    verdict="CRASH (exit $rc)"
  else
    verdict=ok
  fi
  took=$(($(date +%s) - started))
  echo "fuzz $target: ${runs:-?} executions in $took s (${rate:-?} exec/s), cov ${cov:-?}, ft ${ft:-?}, corpus ${corp:-?}: $verdict"
done
if [ "${#failed[@]}" -gt 0 ]; then
  echo "fuzz: crashed: ${failed[*]} (inputs under fuzz/artifacts/)" >&2
  exit 1
fi
