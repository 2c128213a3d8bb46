#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The CAN mirror from the host: the committed DBC is current, --print-dbc
follows the configuration, bad [can] settings exit 2, and a mirror whose
interface does not exist leaves Modbus serving while it counts and retries.
The frames themselves are tested on a real kernel CAN stack in a VM
(tests/can/test_can_vm.py, make test-can)."""
import os
import subprocess
import tempfile
import time

from harness import (JAKAGW, check, raw_client, read_input_registers, running, run,
                     wait_until)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
SHIPPED_CONF = os.path.join(ROOT, "config", "jakagw.conf")

# Input registers of the CAN mirror's diagnostics (docs/register-map.md).
CAN_STATE, CAN_FRAMES_SENT, CAN_FRAMES_DROPPED, CAN_ERRORS = 50, 52, 54, 56


def jakagw(*args):
    return subprocess.run([JAKAGW] + list(args), capture_output=True, text=True, timeout=10)


def with_conf(text, *args):
    with tempfile.NamedTemporaryFile("w", suffix=".conf", delete=False) as f:
        f.write(text)
    try:
        return jakagw("-c", f.name, *args)
    finally:
        os.unlink(f.name)


def test_committed_dbc_is_current():
    with open(os.path.join(ROOT, "docs", "jakagw.dbc")) as f:
        committed = f.read()
    r = jakagw("-c", SHIPPED_CONF, "--print-dbc")
    check(r.returncode == 0, r.stderr)
    check(committed == r.stdout,
          "docs/jakagw.dbc is out of date: run 'make docs' and commit it")


def test_print_dbc_follows_the_configuration():
    r = with_conf("[can]\nbase_id = 0x18ff0000\nextended_ids = true\nperiod_ms = 20\n"
                  "frames = health, joints\n", "--print-dbc")
    check(r.returncode == 0, r.stderr)
    ids = [line.split()[1] for line in r.stdout.splitlines() if line.startswith("BO_ ")]
    check(ids == [str(0x80000000 | (0x18FF0000 + k)) for k in (1, 3, 4, 5)], ids)
    check('BA_ "GenMsgCycleTime" BO_ %d 20;' % (0x80000000 | 0x18FF0001) in r.stdout,
          "cycle time")


def test_bad_can_settings_exit_2():
    cases = [
        ("[can]\nenabled = true\n", "[can] enabled: true needs an interface"),
        ("[can]\nenabled = true\ninterface = vcan0\nbase_id = 0x7fc\n",
         "[can] base_id: 0x7FC leaves no room for the frames"),
        ("[can]\nframes = state, pose\n", "[can] frames: 'pose' is not a frame group"),
        ("[can]\nperiod_ms = 1\n", "[can] period_ms: 1 is out of range 5..10000"),
        ("[can]\ninterface = can 0\n", "not a network interface name"),
    ]
    for text, message in cases:
        r = with_conf(text, "--check-config")
        check(r.returncode == 2, "%r: exit %d" % (text, r.returncode))
        check(message in r.stderr, "%r: %r lacks %r" % (text, r.stderr, message))
    r = with_conf("[can]\nenabled = true\n", "--print-dbc")
    check(r.returncode == 2, "--print-dbc with a bad configuration: exit %d" % r.returncode)


def u32(sock, address):
    hi, lo = read_input_registers(sock, address, 2)
    return hi << 16 | lo


def test_absent_interface_leaves_modbus_serving():
    """No interface of that name: the mirror counts, logs once and keeps
    trying with backoff; Modbus answers and shows the counters."""
    conf = "[can]\nenabled = true\ninterface = jakagwcan9\nperiod_ms = 10\n"
    with running(("--test-pattern",), conf) as (sim, gw):
        with raw_client(gw.modbus_port) as s:
            wait_until(lambda: read_input_registers(s, 104, 2) == [3, 2], 10,
                       "the test pattern's tool and user id")
            check(read_input_registers(s, CAN_STATE, 1) == [5], "can_state is not 5 (absent)")
            first = u32(s, CAN_ERRORS)
            wait_until(lambda: u32(s, CAN_ERRORS) > first, 10, "another open attempt")
            check(u32(s, CAN_FRAMES_SENT) == 0, "frames sent to no interface")
            dropped = u32(s, CAN_FRAMES_DROPPED)
            check(dropped > 0 and dropped % 9 == 0, "dropped %d" % dropped)
            start = time.monotonic()
            for i in range(200):
                read_input_registers(s, 0, 10, tid=i + 2)
            elapsed = time.monotonic() - start
        out = gw.output()
    check(out.count("no such interface") == 1,
          "the absent interface was not logged exactly once:\n" + out)
    print("  200 Modbus reads in %.3f s while the mirror retried" % elapsed)


if __name__ == "__main__":
    run([test_committed_dbc_is_current, test_print_dbc_follows_the_configuration,
         test_bad_can_settings_exit_2, test_absent_interface_leaves_modbus_serving])
