#!/bin/sh
# Runs every test against the plain build (build/) and the ASan+UBSan build
# (build-san/): the cmocka unit tests, then the integration tests, which
# start the real jakasim and jakagw on free loopback ports.
#
#   tests/run.sh              everything
#   tests/run.sh unit         unit tests only (VALGRIND=1: under valgrind)
#   BUILDS="build" tests/run.sh   one build only
set -u
cd "$(dirname "$0")/.."

what=${1:-all}
BUILDS=${BUILDS:-"build build-san"}
PYTHON=${PYTHON:-/usr/bin/python3}
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=0:exitcode=23}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
passed=0
failed=0
failures=""

record() { # name status
    if [ "$2" -eq 0 ]; then
        passed=$((passed + 1))
    else
        failed=$((failed + 1))
        failures="$failures $1"
    fi
}

for build in $BUILDS; do
    [ -x "$build/jakagw" ] || { echo "missing $build/jakagw: run make first" >&2; exit 2; }
    for t in "$build"/tests/test_*; do
        case "$t" in *.d) continue ;; esac
        echo "== $t"
        if [ "${VALGRIND:-0}" = 1 ]; then
            valgrind -q --error-exitcode=99 --leak-check=full --errors-for-leak-kinds=definite "$t"
        else
            "$t"
        fi
        record "$t" $?
    done
    [ "$what" = unit ] && continue
    for t in tests/integration/test_*.py; do
        echo "== $t ($build)"
        JAKAGW_BIN_DIR="$build" "$PYTHON" "$t"
        record "$t($build)" $?
    done
done

echo
[ -n "$failures" ] && echo "failed:$failures"
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
