#!/bin/bash
# Runs each libFuzzer target for FUZZ_SECONDS (default 60) from its
# committed seeds (fuzz/seeds/NAME for fuzz_NAME), in a fresh corpus, with
# a 10 s limit per input. Prints one line per target with its runs; a
# crash, a leak, a sanitizer report or a hang fails the run with one line:
#   fuzz-ci: FAILED fuzz_NAME: <what> - input saved as <artifact>
# (reproduce with: BUILD/fuzz_NAME <artifact>).
#
#   fuzz/run-ci.sh BUILD_DIR TARGET...
set -u
cd "$(dirname "$0")/.."
build=$1
shift
seconds=${FUZZ_SECONDS:-60}
failed=0
passed=0
summary=""

for t in "$@"; do
    name=${t#fuzz_}
    work=$build/ci/$name
    rm -rf "$work"
    mkdir -p "$work/corpus"
    log=$work/log
    extra=()
    [ "$t" = fuzz_stream ] && extra+=(-max_len=20000)
    [ "$t" = fuzz_config ] && extra+=(-max_len=4096)
    # libFuzzer stops itself after 'seconds'; the outer limit only catches
    # a process that no longer reaches its own alarm.
    timeout -k 10 $((seconds + 120)) "$build/$t" -max_total_time="$seconds" -timeout=10 \
        -rss_limit_mb=2048 -print_final_stats=1 -artifact_prefix="$work/" "${extra[@]}" \
        "$work/corpus" "fuzz/seeds/$name" >"$log" 2>&1
    status=$?
    runs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -1)
    if [ "$status" -eq 0 ]; then
        passed=$((passed + 1))
        echo "fuzz-ci: $t: ${runs:-?} runs in ${seconds} s, $(ls "$work/corpus" | wc -l) new inputs, no crash"
        summary="$summary $t=${runs:-?}"
        continue
    fi
    failed=$((failed + 1))
    artifact=$(sed -n 's/.*Test unit written to \(.*\)$/\1/p' "$log" | tail -1)
    what=$(grep -m1 -E '^==[0-9]+==ERROR|^SUMMARY|runtime error|rule broken|ALARM|out-of-memory|deadly signal' "$log" |
           sed 's/^==[0-9]*==//' | cut -c1-200)
    [ "$status" -eq 124 ] && what="did not stop within $((seconds + 120)) s"
    tail -n 40 "$log"
    echo "fuzz-ci: FAILED $t: ${what:-exit status $status} - input saved as ${artifact:-none} (log $log)"
done

# Not in the "N passed, N failed" form: the test suite's line stays the count.
echo "fuzz-ci: $((passed + failed)) targets, $failed crashed or hung; runs:$summary"
[ "$failed" -eq 0 ]
