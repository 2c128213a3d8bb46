#!/bin/sh
# SPDX-License-Identifier: MIT
# make prove: Frama-C's WP proves the wire-facing checks free of runtime
# errors (-wp-rte: every array index, pointer access, shift and signed
# operation) and true to their ACSL contracts, which sit beside the code
# (a public function's in its header, loop annotations above the loop).
#
#   scripts/prove.sh BUILD_DIR "CPP_FLAGS"
#
# Proves every function of src/modbus/mb_request.c, and rtu_frame.c's CRC
# and length functions (RTU_FUNCTIONS below; the frame walk is not proved).
# Prints "N of N goals proved" per file and fails on any goal not proved,
# or on a parse error or a function called without a contract. Then it
# checks itself: a copy of mb_request.c with one bound removed must fail.
#
# Environment: PROVE_TIMEOUT, seconds per goal and prover (default 30: a
# goal takes 0.3 s alone, and more than 5 s on a loaded machine);
# PROVE_JOBS, provers run at once (default 2).
set -eu

BUILD=$1
CPP_FLAGS=$2
OUT=$BUILD/prove
TIMEOUT=${PROVE_TIMEOUT:-30}
JOBS=${PROVE_JOBS:-2}

# The named rtu_frame.c functions: the CRC, the character times, and the
# lengths a frame's own bytes or its request give.
RTU_FUNCTIONS=rtu_crc16,rtu_crc_ok,rtu_append_crc,rtu_char_times,rtu_request_length,\
device_id_length,own_length,rtu_response_length,response_form_length,lacking,\
least_lacking,whole_frame,response_reading,response_lacking

for cmd in frama-c why3 z3 cvc4; do
    command -v $cmd >/dev/null 2>&1 ||
        { echo "prove: no $cmd: run 'make deps' first (group prove)" >&2; exit 1; }
done
mkdir -p "$OUT"

# why3 finds its provers only through a configuration file, which a fresh
# machine does not have: made here, in the build directory, every run.
WHY3CONFIG=$(pwd)/$OUT/why3.conf
export WHY3CONFIG
why3 config detect -C "$WHY3CONFIG" >"$OUT/why3-detect.log" 2>&1 ||
    { echo "prove: why3 config detect failed:" >&2; cat "$OUT/why3-detect.log" >&2; exit 1; }
for p in Z3 CVC4; do
    grep -q "Found prover $p version.*, OK" "$OUT/why3-detect.log" ||
        { echo "prove: why3 does not take $p:" >&2; cat "$OUT/why3-detect.log" >&2; exit 1; }
done

# The functions a file defines (a definition starts at the line's start).
functions_of() {
    sed -n 's/^[a-z][^(=;]*[ *]\([a-z_][a-z0-9_]*\)(.*/\1/p' "$1" | sort -u | paste -sd, -
}

# run_wp LABEL FILE FUNCTIONS TIMEOUT: the goals of FUNCTIONS in FILE;
# writes OUT/LABEL.log, prints its tally, returns 0 only if every goal
# was proved.
run_wp() {
    label=$1 file=$2 fcts=$3 limit=$4
    log=$OUT/$label.log
    status=0
    frama-c -cpp-extra-args="$CPP_FLAGS" \
        -kernel-warn-key annot:missing-spec=abort \
        -wp -wp-rte -wp-fct "$fcts" -wp-prover z3,cvc4 -wp-timeout "$limit" \
        -wp-par "$JOBS" -wp-cache none -wp-session "$OUT/$label.session" \
        "$file" >"$log" 2>&1 || status=$?
    tally=$(sed -n 's/^\[wp\] Proved goals: *\([0-9]*\) *\/ *\([0-9]*\)$/\1 \2/p' "$log" | tail -n 1)
    if [ "$status" -ne 0 ] || [ -z "$tally" ]; then
        echo "prove: $file: frama-c failed (exit status $status), see $log:" >&2
        grep -i "error\|abort" "$log" | head -n 5 >&2
        return 1
    fi
    set -- $tally
    echo "prove: $file: $1 of $2 goals proved"
    if [ "$1" -ne "$2" ] || [ "$2" -eq 0 ]; then
        grep -A2 "^\[wp\] \[\(Failed\|Timeout\|Unknown\|Stepout\)\]" "$log" | sed 's/^/prove:   /' >&2
        return 1
    fi
}

failed=0
run_wp mb_request src/modbus/mb_request.c "$(functions_of src/modbus/mb_request.c)" \
    "$TIMEOUT" || failed=1
run_wp rtu_frame src/modbus/rtu_frame.c "$RTU_FUNCTIONS" "$TIMEOUT" || failed=1
[ "$failed" -eq 0 ] || { echo "prove: FAILED: goals not proved (logs in $OUT)" >&2; exit 1; }

# The check must be able to fail: check_write_coils without its
# quantity's upper bound takes up to 2033 coils (a byte count of 255) into
# its array of 1968, which the runtime-error goals forbid. The goal fails
# at once (the provers answer, no timeout waited).
mutant=$OUT/mutant/mb_request.c
mkdir -p "$OUT/mutant"
sed 's/count > MODBUS_MAX_WRITE_BITS || bytes != (count + 7) \/ 8/bytes != (count + 7) \/ 8/' \
    src/modbus/mb_request.c >"$mutant"
if cmp -s src/modbus/mb_request.c "$mutant"; then
    echo "prove: the self-check's bound (check_write_coils's 'count > MODBUS_MAX_WRITE_BITS') is gone from mb_request.c: update scripts/prove.sh" >&2
    exit 1
fi
if run_wp mutant "$mutant" check_write_coils 10 >"$OUT/mutant.out" 2>&1; then
    echo "prove: FAILED: check_write_coils without its bound was proved too (see $OUT/mutant.log)" >&2
    exit 1
fi
grep -q "goals proved" "$OUT/mutant.out" ||
    { echo "prove: FAILED: the self-check did not run:" >&2; cat "$OUT/mutant.out" >&2; exit 1; }
echo "prove: self-check: check_write_coils without its quantity bound:" \
    "$(sed -n 's/^prove: [^:]*: \(.* goals proved\)$/\1/p' "$OUT/mutant.out") (must fail: it does)"
