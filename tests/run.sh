#!/bin/bash
# SPDX-License-Identifier: MIT
# Runs every test against the plain build (build/) and the ASan+UBSan build
# (build-san/): the cmocka unit tests, then the integration tests, which
# start the real jakasim and jakagw on free loopback ports; each build's
# tests are a lane, and the lanes run side by side (the first one's output
# streams, the others' follow it). Ends with one line counting the test
# cases: "N passed, N failed".
#
#   tests/run.sh                  everything
#   tests/run.sh unit             unit tests only (VALGRIND=1: under valgrind)
#   BUILDS=build tests/run.sh     one build only
#   SUITES="status_map commands"  those integration suites only
#
# The fault suite (test_faults.py: each test in its own network namespace,
# with nftables; needs root, as CI runs) runs whole with the first native
# build, two of its cases with the sanitizer build, not at all for ARM.
#
# An ARM build (make test ARCH=arm64|armhf sets BUILDS=build-ARCH,
# JAKAGW_ARCH and JAKAGW_RUNNER): every unit test and every binary the
# integration tests start runs under qemu-user through JAKAGW_RUNNER, the
# one runner prefix ("qemu-arm -L build-armhf/sysroot"). The package test
# then checks the ARCH package (tests/package/test_package.py). The CAN VM
# test boots an amd64 kernel, where ARM binaries cannot run: it runs with
# the amd64 build only, and so does the service VM test (the package under
# systemd in qemu, tests/service/test_service_vm.py), after the package test.
# The alert suite (tests/integration/test_alerts.py, mostly waiting on
# Prometheus) and the PLC library's (tests/plc/test_plc.py, mostly waiting
# on its cells' scans) run beside those two when they run, their output
# after theirs.
set -u
cd "$(dirname "$0")/.."

what=${1:-all}
BUILDS=${BUILDS:-"build build-san"}
PYTHON=${PYTHON:-/usr/bin/python3}
RUNNER=${JAKAGW_RUNNER:-}
SUITES=${SUITES:-}
for name in $SUITES; do
    [ "$name" = plc ] && continue  # tests/plc/test_plc.py
    [ -f "tests/integration/test_$name.py" ] ||
        { echo "SUITES: no tests/integration/test_$name.py" >&2; exit 2; }
done
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1:exitcode=23}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}
passed=0
failed=0
failures=""
log=$(mktemp)
alerts_beside=""
# Suites that wait more than they compute run beside the service VM test,
# which boots and installs (start_beside); their output follows its
# (finish_beside). A suite still running beside
# the others is stopped with the run.
beside_labels=() beside_pids=() beside_logs=() beside_starts=()
lane_pids=()
package_pid=""
trap 'for p in "${beside_pids[@]}" "${lane_pids[@]}" $package_pid; do kill "$p" 2>/dev/null; done
      rm -f "$log" "${beside_logs[@]}"' EXIT

# Each suite's wall time, from the end of the one before it (or from the
# given start, for a suite that ran beside others), printed at the end,
# longest first, so that what CI's time goes to is in every log.
suite_start=$SECONDS
times=""

# Adds a suite's cases to the totals; a suite that exits non-zero without
# reporting a failed case (a crash, a sanitizer abort) counts one failure.
record() { # name exit-status passed-cases failed-cases [start-seconds]
    times="$times$(( SECONDS - ${5:-$suite_start} )) $1"$'\n'
    suite_start=$SECONDS
    passed=$((passed + $3))
    failed=$((failed + $4))
    if [ "$2" -ne 0 ]; then
        failures="$failures $1"
        [ "$4" -eq 0 ] && failed=$((failed + 1))
    fi
}

# Starts a suite in the background, its output into a file of its own.
start_beside() { # label command...
    local label=$1 out
    shift
    out=$(mktemp)
    echo "== $label started beside the service VM test; its output follows it"
    # Its own wall time goes into the table, not the time until collected.
    ( t0=$SECONDS; "$@"; status=$?; echo $((SECONDS - t0)) >"$out.took"; exit $status ) \
        >"$out" 2>&1 &
    beside_labels+=("$label") beside_pids+=($!) beside_logs+=("$out") beside_starts+=($SECONDS)
}

# Waits for every suite started beside, prints its output and records it.
finish_beside() {
    local i status
    for i in "${!beside_pids[@]}"; do
        wait "${beside_pids[$i]}"
        status=$?
        echo "== ${beside_labels[$i]}"
        cat "${beside_logs[$i]}"
        took=$(cat "${beside_logs[$i]}.took" 2>/dev/null)
        record_summary "${beside_labels[$i]}(beside)" "$status" "${beside_logs[$i]}" \
            "$((SECONDS - ${took:-$((SECONDS - beside_starts[$i]))}))"
        rm -f "${beside_logs[$i]}.took"
    done
    beside_pids=()
}

# record() for a suite that printed "N passed, N failed" into a file.
record_summary() { # name exit-status file [start-seconds]
    local line ok bad
    line=$(grep -E '^[0-9]+ passed, [0-9]+ failed$' "$3" | tail -1)
    ok=${line%% passed*}
    bad=${line#*, }
    bad=${bad%% failed}
    record "$1" "$2" "${ok:-0}" "${bad:-0}" "${4:-}"
}

# The alert suite with the first native build goes beside the service VM
# test in a whole run (below).
if [ "$what" = all ] && [ -z "$SUITES" ] && [ -z "${JAKAGW_ARCH:-}" ]; then
    alerts_beside=${BUILDS%% *}
fi
for build in $BUILDS; do
    [ -x "$build/jakagw" ] || { echo "missing $build/jakagw: run make first" >&2; exit 2; }
done

# In a whole native run, these of the first build's suites get a lane of
# their own (about half of its suites' time), beside the rest.
SPLIT_SUITES=""
if [ "$what" = all ] && [ -z "$SUITES" ] && [ -z "${JAKAGW_ARCH:-}" ]; then
    SPLIT_SUITES="http faults link_faults robot_protection tls"
fi

# One build's unit tests, then its integration suites; part "main": the
# unit tests and the suites not in SPLIT_SUITES, "split": those only.
run_build() { # build [all|main|split]
    local build=$1 part=${2:-all} t name suite_args plc_model_runs load_seconds browser_tests status ok bad
    for t in "$build"/tests/test_*; do
        [ "$part" = split ] && break
        case "$t" in *.d) continue ;; esac
        echo "== $t"
        if [ "${VALGRIND:-0}" = 1 ]; then
            valgrind -q --error-exitcode=99 --leak-check=full \
                --errors-for-leak-kinds=definite "$t" 2>&1 | tee "$log"
        else
            # shellcheck disable=SC2086  # the prefix is a command line
            $RUNNER "$t" 2>&1 | tee "$log"
        fi
        status=${PIPESTATUS[0]}
        ok=$(sed -n 's/^\[  PASSED  \] \([0-9]*\) test.*/\1/p' "$log" | tail -1)
        bad=$(sed -n 's/^\[  FAILED  \] \([0-9]*\) test.*/\1/p' "$log" | tail -1)
        record "$t" "$status" "${ok:-0}" "${bad:-0}"
    done
    [ "$what" = unit ] && return
    for t in tests/integration/test_*.py; do
        name=${t#tests/integration/test_}
        name=${name%.py}
        case " ${SUITES:-$name} " in *" $name "*) ;; *) continue ;; esac
        case $part in
            main) [[ " $SPLIT_SUITES " == *" $name "* ]] && continue ;;
            split) [[ " $SPLIT_SUITES " == *" $name "* ]] || continue ;;
        esac
        # The fault suite (network namespaces, nftables; root) runs whole
        # with the first native build (about 70 s); the sanitizer build
        # runs the two cases that go through every fault close (a command
        # into a dead link, resets on both ports: about 11 s); ARM builds
        # under qemu-user do not run it.
        suite_args=""
        if [ "$name" = faults ]; then
            [ -n "${JAKAGW_ARCH:-}" ] && continue
            [ "$build" != "${BUILDS%% *}" ] &&
                suite_args="test_command_into_dead_link_never_delivered test_reset_mid_stream"
        fi
        # The alert rules in a real Prometheus server, every fault in
        # parallel (about 2.5 minutes, nearly all of it waiting for
        # Prometheus's "for" durations): whole with the first native build,
        # beside the service VM test when it runs (below);
        # the sanitizer build runs the gateway's own cases (the stall, the
        # never-seen ages, the stale streak: 16 s) and the promtool
        # replays; ARM builds do not run it.
        if [ "$name" = alerts ]; then
            [ -n "${JAKAGW_ARCH:-}" ] && continue
            [ "$build" = "$alerts_beside" ] && continue
            [ "$build" != "${BUILDS%% *}" ] &&
                suite_args="test_stall_is_the_gateways_own_fault test_never_seen_ages_have_no_sample_and_heartbeat_reads_back test_stale_streak_survives_reconnects_that_bring_documents test_recorded_series_replay_with_promtool"
        fi
        # jakasim's network-exception handling: its nine loss-and-action
        # combinations (17 s) run with the first native build; the others
        # (ARM, sanitizer) run the two-layer test and the handler's scope.
        if [ "$name" = robot_protection ] && [ "$build" != "${BUILDS%% *}" ]; then
            suite_args="test_handler_belongs_to_its_connection test_silent_gateway_pauses_the_program"
        fi
        # The PLC model's generated runs: 150 with the first native build,
        # 40 with the others (sanitizer, ARM under qemu-user); its own
        # default (200) and PLC_MODEL_RUNS for longer runs.
        plc_model_runs=${PLC_MODEL_RUNS:-}
        if [ -z "$plc_model_runs" ]; then
            plc_model_runs=150
            [ "$build" != "${BUILDS%% *}" ] && plc_model_runs=40
        fi
        echo "== $t ($build)"
        # The load test: 40 s with the first native build (40,000 requests
        # beside commands and the heartbeat), 10 s with the sanitizer and
        # ARM builds; make test-load runs its full minute.
        load_seconds=${LOAD_SECONDS:-}
        if [ -z "$load_seconds" ]; then
            load_seconds=40
            { [ "$build" != "${BUILDS%% *}" ] || [ -n "${JAKAGW_ARCH:-}" ]; } && load_seconds=10
        fi
        # shellcheck disable=SC2086  # suite_args: test names
        # The status page's tests in Chromium run with the first build only.
        browser_tests=1
        [ "$build" != "${BUILDS%% *}" ] && browser_tests=0
        PLC_MODEL_RUNS=$plc_model_runs \
        LOAD_SECONDS=$load_seconds JAKAGW_BROWSER_TESTS=$browser_tests JAKAGW_BIN_DIR="$build" \
            "$PYTHON" "$t" $suite_args 2>&1 | tee "$log"
        status=${PIPESTATUS[0]}
        record_summary "$t($build)" "$status" "$log"
    done
}

# The package test (make deb, lintian, apt into a fresh root) and then the
# service VM's image (the previous release's package, mmdebstrap, from the
# package just built) build and install rather than wait: in a whole native
# run they start now, beside the lanes, at nice 10; the VMs boot after the
# lanes, the service VM from that image (its own build of the image finds
# it made; when this one failed, that one says why). Their output follows
# the CAN and netem VMs'.
package_pid=""
if [ "$what" = all ] && [ -z "$SUITES" ] && [ -z "${JAKAGW_ARCH:-}" ]; then
    package_log=$(mktemp) package_state=$(mktemp) package_start=$SECONDS
    ( build=${BUILDS%% *}
      case $build in /*) ;; *) build=$PWD/$build ;; esac
      mark=$(mktemp) t0=$SECONDS
      nice -n 10 "$PYTHON" tests/package/test_package.py "$build" >"$package_log" 2>&1
      echo $? >"$package_state"
      echo $((SECONDS - t0)) >"$package_state.took"
      deb=$(ls -t "$build"/deb/jakagw_*.deb 2>/dev/null | head -n 1)
      if [ -n "$deb" ] && [ "$deb" -nt "$mark" ]; then
          echo "$deb" >>"$package_state"
          t0=$SECONDS
          nice -n 10 "$PYTHON" scripts/make-service-image.py "$build/service-vm" "$deb" \
              >/dev/null 2>"$package_log.image" ||
              echo "made no image: the service VM test makes it again and says why" >>"$package_log.image"
          echo "$((SECONDS - t0)) s beside the lanes" >>"$package_log.image"
      fi
      rm -f "$mark" ) &
    package_pid=$!
    echo "== tests/package/test_package.py and the service VM's image started beside the lanes; the output follows the VMs'"
fi

# The lanes side by side: most suites wait on timers, links and their
# processes far more than they compute, so the first build's split-off
# suites (SPLIT_SUITES) and each other build (the sanitizer build) run
# beside the first build's unit tests and other suites, whose output
# streams as it comes; every other lane's output follows, whole, with its
# totals added.
lane_state=() lane_out=() lane_pids=() lane_builds=()
lanes=()
[ -n "$SPLIT_SUITES" ] && lanes+=("${BUILDS%% *}:split")
for build in ${BUILDS#* }; do
    [ "$build" = "${BUILDS%% *}" ] || lanes+=("$build:all")
done
for lane in "${lanes[@]}"; do
    out=$(mktemp) st=$(mktemp)
    ( log=$(mktemp)
      passed=0 failed=0 failures="" times="" suite_start=$SECONDS
      run_build "${lane%:*}" "${lane##*:}" >"$out" 2>&1
      rm -f "$log"
      { echo "$passed"; echo "$failed"; echo "$failures"; printf '%s' "$times"; } >"$st" ) &
    lane_pids+=($!) lane_out+=("$out") lane_state+=("$st") lane_builds+=("$lane")
    echo "== the $lane lane started beside ${BUILDS%% *}'s; its output follows"
done
run_build "${BUILDS%% *}" main
for i in "${!lane_pids[@]}"; do
    wait "${lane_pids[$i]}"
    cat "${lane_out[$i]}"
    p="" f="" fl="" t=""
    { read -r p; read -r f; read -r fl; t=$(cat); } <"${lane_state[$i]}"
    if [ -z "$p" ]; then  # the lane itself died: one failure, named
        failed=$((failed + 1))
        failures="$failures ${lane_builds[$i]}(its lane died)"
        continue
    fi
    passed=$((passed + p))
    failed=$((failed + f))
    failures="$failures$fl"
    [ -n "$t" ] && times="$times$t"$'\n'
    rm -f "${lane_out[$i]}" "${lane_state[$i]}"
done
suite_start=$SECONDS

# The PLC library run as a PLC (make test-plc): once, with the first
# native build; SUITES leaves it out unless it names plc.
# In a whole run it goes beside the service VM test (below): about two minutes,
# most of them the vendor clients' cells waiting on their scans.
plc_beside=""
if [ "$what" = all ] && [ -z "${JAKAGW_ARCH:-}" ] &&
   { [ -z "$SUITES" ] || [[ " $SUITES " == *" plc "* ]]; }; then
    build=${BUILDS%% *}
    if [ -z "$SUITES" ]; then
        plc_beside=$build
    else
        echo "== tests/plc/test_plc.py ($build)"
        JAKAGW_BIN_DIR="$build" "$PYTHON" tests/plc/test_plc.py 2>&1 | tee "$log"
        status=${PIPESTATUS[0]}
        record_summary "tests/plc/test_plc.py($build)" "$status" "$log"
    fi
fi

# The CAN mirror on a real kernel CAN stack, and netem on single links, in
# VMs: once, with the first build.
if [ "$what" = all ] && [ -z "$SUITES" ] && [ -z "${JAKAGW_ARCH:-}" ]; then
    build=${BUILDS%% *}
    echo "== tests/can/test_can_vm.py ($build)"
    JAKAGW_BIN_DIR="$build" "$PYTHON" tests/can/test_can_vm.py 2>&1 | tee "$log"
    status=${PIPESTATUS[0]}
    record_summary "tests/can/test_can_vm.py($build)" "$status" "$log"
    # Latency, jitter, reordering, duplication and a rate limit (sch_netem),
    # in one more boot of the same kernel: about 2.5 minutes.
    echo "== tests/can/test_netem_vm.py ($build)"
    # Its 200 ms trials 10 times and its false-trip table with 2 trials per
    # cell here (make test-netem: 20 and 5).
    JAKAGW_NETEM_TRIALS=${JAKAGW_NETEM_TRIALS:-10} \
    JAKAGW_NETEM_TABLE_TRIALS=${JAKAGW_NETEM_TABLE_TRIALS:-2} JAKAGW_BIN_DIR="$build" \
        "$PYTHON" tests/can/test_netem_vm.py 2>&1 | tee "$log"
    status=${PIPESTATUS[0]}
    record_summary "tests/can/test_netem_vm.py($build)" "$status" "$log"
fi

# The Debian package, built and installed into a fresh Debian 12 root file
# system (also make test-package): once, with the first build. For an ARM
# build, its package: built, checked and run under qemu-user. SUITES leaves
# it out unless WITH_PACKAGE=1.
if [ "$what" = all ] && { [ -z "$SUITES" ] || [ "${WITH_PACKAGE:-0}" = 1 ]; }; then
    build=${BUILDS%% *}
    # The alert suite waits on Prometheus most of its 2.5 minutes, and the
    # PLC library's cells on their scans: both use little CPU and run beside
    # the service VM test (and the package test when it was not made beside
    # the lanes), their output after those tests'.
    [ -n "$alerts_beside" ] && JAKAGW_BIN_DIR="$alerts_beside" \
        start_beside "tests/integration/test_alerts.py($alerts_beside)" \
        "$PYTHON" tests/integration/test_alerts.py
    [ -n "$plc_beside" ] && JAKAGW_BIN_DIR="$plc_beside" \
        start_beside "tests/plc/test_plc.py($plc_beside)" "$PYTHON" tests/plc/test_plc.py
    deb=""
    if [ -n "$package_pid" ]; then
        wait "$package_pid"
        package_pid=""
        echo "== tests/package/test_package.py ($build, beside the lanes)"
        cat "$package_log"
        sed 's/^/  service image: /' "$package_log.image" 2>/dev/null
        status="" deb=""
        { read -r status; read -r deb; } <"$package_state"
        took=$(cat "$package_state.took" 2>/dev/null)
        record_summary "tests/package/test_package.py(beside the lanes)" "${status:-1}" "$package_log" \
            "$((SECONDS - ${took:-$((SECONDS - package_start))}))"
        rm -f "$package_log" "$package_log.image" "$package_state" "$package_state.took"
    else
        echo "== tests/package/test_package.py ($build)"
        package_mark=$(mktemp)
        "$PYTHON" tests/package/test_package.py "$build" 2>&1 | tee "$log"
        status=${PIPESTATUS[0]}
        record_summary "tests/package/test_package.py" "$status" "$log"
        deb=$(ls -t "$build"/deb/jakagw_*.deb 2>/dev/null | head -n 1)
        [ -n "$deb" ] && [ "$deb" -nt "$package_mark" ] || deb=""
        rm -f "$package_mark"
    fi

    # The installed package under systemd in a VM (also make test-service):
    # once, with the first native build, on the package the package test
    # has just built (when it did; the VM test runs make deb otherwise).
    if [ -z "${JAKAGW_ARCH:-}" ]; then
        echo "== tests/service/test_service_vm.py ($build)"
        [ -n "$deb" ] && export JAKAGW_SERVICE_DEB=$deb
        "$PYTHON" tests/service/test_service_vm.py "$build" 2>&1 | tee "$log"
        status=${PIPESTATUS[0]}
        unset JAKAGW_SERVICE_DEB
        record_summary "tests/service/test_service_vm.py" "$status" "$log"
    fi
    finish_beside
fi

echo
echo "wall time per suite (s), longest first:"
printf '%s' "$times" | sort -rn | head -n 25 | sed 's/^/  /'
[ -n "$failures" ] && echo "failed suites:$failures"
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ] && [ -z "$failures" ]
