#!/bin/bash
# SPDX-License-Identifier: MIT
# Runs each libFuzzer target for FUZZ_SECONDS (default 60) from its
# committed seeds (fuzz/seeds/NAME for fuzz_NAME), in a fresh corpus, with
# a 10 s limit per input, FUZZ_JOBS (default 2) targets at a time. Prints
# one line per target with its runs; a crash, a leak, a sanitizer report or
# a hang fails the run with one line:
#   fuzz-ci: FAILED fuzz_NAME: <what> - input saved as <artifact>
# (reproduce with: BUILD_DIR/fuzz_NAME <artifact>).
#
#   fuzz/run-ci.sh BUILD_DIR TARGET...
set -u
cd "$(dirname "$0")/.."
build=$1
shift
seconds=${FUZZ_SECONDS:-60}
jobs=${FUZZ_JOBS:-2}

# Runs one target; leaves its report in $build/ci/NAME/result.
run_one() { # target
    local t=$1 name=${1#fuzz_} status runs artifact what extra=()
    local work=$build/ci/$name
    rm -rf "$work"
    mkdir -p "$work/corpus"
    [ "$t" = fuzz_stream ] && extra+=(-max_len=20000)
    [ "$t" = fuzz_config ] && extra+=(-max_len=4096)
    # libFuzzer stops itself after 'seconds'; the outer limit only catches
    # a process that no longer reaches its own alarm.
    timeout -k 10 $((seconds + 120)) "$build/$t" -max_total_time="$seconds" -timeout=10 \
        -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$work/" "${extra[@]}" \
        "$work/corpus" "fuzz/seeds/$name" >"$work/log" 2>&1
    status=$?
    runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$work/log" | tail -1)
    if [ "$status" -eq 0 ]; then
        echo "fuzz-ci: $t: ${runs:-?} runs in $seconds s, $(ls "$work/corpus" | wc -l)" \
            "new inputs, no crash" >"$work/result"
        return 0
    fi
    artifact=$(sed -n 's/.*Test unit written to \(.*\)$/\1/p' "$work/log" | tail -1)
    what=$(grep -m1 -E '^==[0-9]+==ERROR|runtime error|rule broken|ALARM|out-of-memory|deadly signal' \
        "$work/log" | sed 's/^==[0-9]*==//' | cut -c1-200)
    [ "$status" -eq 124 ] && what="did not stop within $((seconds + 120)) s"
    echo "fuzz-ci: FAILED $t: ${what:-exit status $status} - input saved as" \
        "${artifact:-none} (log $work/log)" >"$work/result"
    return 1
}

running=0
for t in "$@"; do
    if [ "$running" -ge "$jobs" ]; then
        wait -n
        running=$((running - 1))
    fi
    run_one "$t" &
    running=$((running + 1))
done
wait

failed=0
summary=""
for t in "$@"; do
    result=$build/ci/${t#fuzz_}/result
    if [ ! -f "$result" ] || grep -q FAILED "$result"; then
        failed=$((failed + 1))
        tail -n 30 "$build/ci/${t#fuzz_}/log"
    fi
    summary="$summary $t=$(sed -n 's/^stat::number_of_executed_units: *//p' "$build/ci/${t#fuzz_}/log" | tail -1)"
done
# The one line per target last, failures included, so they end the output.
for t in "$@"; do
    cat "$build/ci/${t#fuzz_}/result" 2>/dev/null || echo "fuzz-ci: FAILED $t: no result"
done
# Not in the "N passed, N failed" form: the test suite's line stays the count.
echo "fuzz-ci: $# targets, $failed crashed or hung; runs:$summary"
[ "$failed" -eq 0 ]
