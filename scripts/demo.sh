#!/bin/sh
# SPDX-License-Identifier: MIT
# Runs jakasim (a simulated robot running a program, so values move) and
# jakagw in front of it. Modbus TCP on 127.0.0.1:1502 unless MODBUS_BIND /
# MODBUS_PORT say otherwise; the status page and /metrics on
# http://127.0.0.1:10502/ unless HTTP_PORT says otherwise. Ctrl-C stops
# both. DEMO_SECONDS=N stops after N s.
#
# Both run in sessions of their own, so that Ctrl-C reaches this script
# only: it stops the gateway first, then the simulator (stopped the other
# way round, the gateway would log the robot's going as a lost connection),
# and ends with status 0, as a demo that was asked to stop.
set -eu
cd "$(dirname "$0")/.."
MODBUS_BIND=${MODBUS_BIND:-127.0.0.1}
MODBUS_PORT=${MODBUS_PORT:-1502}
STATUS_PORT=${STATUS_PORT:-10000}
COMMAND_PORT=${COMMAND_PORT:-10001}
HTTP_PORT=${HTTP_PORT:-10502}
CONF=$(mktemp)
printf '[http]\nenabled = true\nport = %s\n' "$HTTP_PORT" > "$CONF"

setsid build/jakasim --status-port "$STATUS_PORT" --command-port "$COMMAND_PORT" --auto-run &
SIM=$!
GW=
stop() { # pid: SIGTERM, and wait until it has exited
    if [ -n "$1" ] && kill -TERM "$1" 2>/dev/null; then
        wait "$1" 2>/dev/null || true
    fi
}
cleanup() {
    trap - EXIT INT TERM HUP
    stop "$GW"
    stop "$SIM"
    rm -f "$CONF"
}
trap cleanup EXIT
trap 'cleanup; exit 0' INT TERM HUP

cat <<MSG

jakagw demo: the simulated robot runs a program; its status is served over
Modbus TCP on $MODBUS_BIND:$MODBUS_PORT. In another terminal, try:

  mbpoll -m tcp -p $MODBUS_PORT -t 3 -r 1 -c 20 $MODBUS_BIND            # self-description, diagnostics
  mbpoll -m tcp -p $MODBUS_PORT -t 3:float -B -r 201 -c 6 $MODBUS_BIND  # joint positions (deg), moving
  mbpoll -m tcp -p $MODBUS_PORT -t 1 -r 17 -c 8 $MODBUS_BIND            # robot flags

The status page: http://127.0.0.1:$HTTP_PORT/ (metrics: /metrics).
Register map: docs/register-map.md. Press Ctrl-C to stop.

MSG
setsid build/jakagw -c "$CONF" --robot-host 127.0.0.1 --status-port "$STATUS_PORT" \
    --command-port "$COMMAND_PORT" --modbus-bind "$MODBUS_BIND" --modbus-port "$MODBUS_PORT" &
GW=$!
if [ -n "${DEMO_SECONDS:-}" ]; then
    sleep "$DEMO_SECONDS"
    cleanup
    exit 0
fi
# The gateway ending on its own (its port taken, say) ends the demo with
# its exit status.
status=0
wait "$GW" || status=$?
GW=
cleanup
exit "$status"
