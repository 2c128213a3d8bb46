#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The CAN mirror on a real kernel CAN stack.

Boots Debian's kernel (linux-image-amd64) in qemu without KVM, from an
initramfs this test builds: busybox-static, the kernel's can, can-raw,
can-dev and vcan modules, the build's jakagw and jakasim, candump and mbpoll,
with every shared library ldd lists. Inside, jakasim replays a status
document made here from the simulator's test pattern (with some fields left
out, one value past the signal's range), jakagw mirrors it on vcan0 every
20 ms, and candump -L records the frames; then vcan0 is taken down and up,
deleted and created again while mbpoll reads the gateway's CAN counters
over Modbus. The captures come back on the serial console, gzipped and
base64-encoded between markers.

On the host every frame is decoded with docs/jakagw.dbc using cantools (from
PyPI, in a venv this test makes under the build directory) and compared with
the document; the frame period's jitter is measured and reported.

    tests/can/test_can_vm.py          (make test-can)
    JAKAGW_BIN_DIR=build              which build's binaries
    JAKAGW_CAN_KEEP=1                 keep the work directory and print it
"""
import json
import os
import re
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))

import vm  # noqa: E402
from harness import JAKAGW, JAKASIM, TestFailure, check, run  # noqa: E402

PERIOD_MS = 20
CAPTURE_S = 5
MODBUS_PORT = 1502
MODULES = ["can", "can-raw", "can-dev", "vcan"]
BOOT_TIMEOUT_S = 240
DBC = os.path.join(ROOT, "docs", "jakagw.dbc")


# ---- the initramfs ----

def test_document():
    """The simulator's test pattern with fields left out, one joint short and
    one value past its signal's range, framed as a controller frames it."""
    out = subprocess.run([JAKASIM, "--test-pattern", "--print-status"], check=True,
                         capture_output=True, text=True).stdout
    doc = json.loads(out)
    del doc["protective_stop"]
    del doc["current_user_id"]
    doc["paused"] = True
    doc["joint_actual_position"] = [-263.40236, 106.90883, 75.54514, 89.82753, -0.0004]
    doc["actual_position"][5] = 1e7  # saturates
    doc.pop("len")
    n = 0
    while True:
        text = json.dumps(dict([("len", n)] + list(doc.items())))
        if len(text) == n:
            return dict([("len", n)] + list(doc.items())), text
        n = len(text)


INIT = r"""counters() { mbpoll -m tcp -p @PORT@ -t 3 -0 -r 50 -c 8 -1 127.0.0.1 > /tmp/mb-$1.txt 2>&1; }
ip link add vcan0 type vcan && ip link set vcan0 up || echo "@@error vcan0"
event booted
cd /tmp
jakasim --replay /test/status.json > /tmp/sim.log 2>&1 &
SIM=$!
jakagw -c /test/jakagw.conf > /tmp/gw.log 2>&1 &
GW=$!
i=0
while [ $i -lt 300 ] && ! grep -q "status link: connected" /tmp/gw.log; do
    usleep 100000; i=$((i + 1))
done
usleep 500000
event capture
candump -L vcan0 > /tmp/capture.log &
CD=$!
sleep @CAPTURE@
kill $CD
counters sending
candump -L any > /tmp/outage.log &
CD=$!
sleep 1
event down
ip link set vcan0 down
sleep 1
counters down
event up
ip link set vcan0 up
sleep 1
counters up
event deleted
ip link del vcan0
sleep 1
counters absent
event created
ip link add vcan0 type vcan && ip link set vcan0 up
sleep 3
counters again
kill $CD
kill $GW; wait $GW; echo "@@exit jakagw $?"
kill $SIM; wait $SIM; echo "@@exit jakasim $?"
"""
FILES = "capture.log outage.log gw.log sim.log mb-*.txt"

CONF = """[robot]
host = 127.0.0.1
[modbus]
bind = 127.0.0.1
port = %d
[can]
enabled = true
interface = vcan0
period_ms = %d
""" % (MODBUS_PORT, PERIOD_MS)


def build_initramfs(version, document_text):
    fs = vm.Initramfs(version)
    fs.program(JAKAGW, "/bin/jakagw")
    fs.program(JAKASIM, "/bin/jakasim")
    for tool in ("candump", "mbpoll"):
        fs.tool(tool)
    fs.kernel_modules(MODULES)
    fs.init(INIT.replace("@PORT@", str(MODBUS_PORT)).replace("@CAPTURE@", str(CAPTURE_S)),
            FILES)
    fs.file("/test/jakagw.conf", CONF)
    fs.file("/test/status.json", document_text)
    return fs.image()


# ---- the run ----

RESULT = None
DOCUMENT = None


def boot():
    global RESULT, DOCUMENT
    kernel, version = vm.find_kernel()
    DOCUMENT, text = test_document()
    RESULT = vm.boot(kernel, build_initramfs(version, text), BOOT_TIMEOUT_S, "JAKAGW_CAN_KEEP")
    print("  kernel %s; VM wall time %.1f s (boot to capture %.1f s)"
          % (version, RESULT.wall_s, RESULT.events.get("capture", 0)))


candump_frames = vm.candump_frames


def modbus_counters(name):
    text = RESULT.files.get("mb-%s.txt" % name, "")
    regs = {int(a): int(v) for a, v in re.findall(r"\[(\d+)\]:\s+(-?\d+)", text)}
    check(len(regs) == 8, "mbpoll (%s) got no answer from the gateway:\n%s" % (name, text))
    u32 = lambda a: (regs[a] & 0xFFFF) << 16 | (regs[a + 1] & 0xFFFF)
    return {"state": regs[50], "sent": u32(52), "dropped": u32(54), "errors": u32(56)}


def decoded(db, frames):
    out = []
    for t, _, can_id, data in frames:
        msg = db.get_message_by_frame_id(can_id)
        check(len(data) == msg.length, "%s: %d bytes, DBC says %d" % (msg.name, len(data),
                                                                        msg.length))
        out.append((t, msg.name, msg.decode(data, decode_choices=True)))
    return out


def shown(value):
    """A decoded value: the name of a named raw value, or the number."""
    return getattr(value, "name", value)


# ---- the checks ----

def test_vm_runs_gateway_and_simulator():
    boot()
    check(RESULT.exits.get("jakagw") == 0, "jakagw exit %s:\n%s"
          % (RESULT.exits.get("jakagw"), RESULT.files.get("gw.log")))
    check(RESULT.exits.get("jakasim") == 0, "jakasim exit %s" % RESULT.exits.get("jakasim"))


def require_run():
    if RESULT is None:
        raise TestFailure("no VM run")


def test_every_frame_decodes_to_the_document():
    import cantools
    require_run()
    db = cantools.database.load_file(DBC)
    frames = candump_frames(RESULT.files["capture.log"])
    check(len(frames) > 0, "no frames captured:\n" + RESULT.files["gw.log"])
    names = {m.name for m in db.messages}
    seen = set()
    d = DOCUMENT
    flags = {"PoweredOn": "powered_on", "Enabled": "enabled", "Paused": "paused",
             "InPosition": "inpos", "EmergencyStop": "emergency_stop",
             "ProtectiveStop": "protective_stop", "OnSoftLimit": "on_soft_limit",
             "DragMode": "drag_status"}
    expect = {k: ("NotSent" if v not in d else ("True" if d[v] else "False"))
              for k, v in flags.items()}
    expect.update({
        "TaskState": {1: "PoweredOff", 2: "PoweredOn", 3: "Disabled", 4: "Enabled"}[d["task_state"]],
        "TaskMode": {1: "Manual", 2: "Automatic", 3: "Reserved", 4: "Drag"}[d["task_mode"]],
        "ProgramState": {0: "Idle", 1: "Loading", 2: "Paused", 3: "Running"}[d["interp_state"]],
        "ToolId": d["current_tool_id"],
        "UserId": "NotSent",
        "ErrorCode": int(d["errcode"], 16),
        "RapidRate": round(d["rapidrate"] * 100, 1),
    })
    for i in range(6):
        jp = d["joint_actual_position"]
        expect["Joint%dPosition" % (i + 1)] = round(jp[i], 3) + 0.0 if i < len(jp) else "NotSent"
    for i, name in enumerate(("TcpX", "TcpY", "TcpZ", "TcpRx", "TcpRy", "TcpRz")):
        expect[name] = round(d["actual_position"][i], 3) + 0.0
    expect["TcpRz"] = 2147483.647  # 1e7 saturates short of the NotSent marker
    counters = []
    for t, name, values in decoded(db, frames):
        seen.add(name)
        for signal, value in values.items():
            value = shown(value)
            if signal in expect:
                want = expect[signal]
                ok = (value == want if isinstance(want, str) or isinstance(value, str)
                      else abs(value - want) < 1e-6)
                check(ok, "%s.%s = %r, the document says %r" % (name, signal, value, want))
        if name == "JAKA_Health":
            check(values["StatusLinkUp"] == 1 and values["CommandLinkUp"] == 1
                  and values["StatusFresh"] == 1, "health %s" % values)
            check(0 <= shown(values["StatusAgeMs"]) < 1000, "status age %s" % values)
            check(values["FramesDropped"] == 0, "frames dropped on a healthy bus: %s" % values)
            counters.append(values["RollingCounter"])
    check(seen == names, "frames never seen: %s" % sorted(names - seen))
    steps = {(b - a) % 256 for a, b in zip(counters, counters[1:])}
    check(steps == {1}, "the rolling counter did not add 1 each period: steps %s" % steps)
    print("  %d frames of %d kinds decoded, every signal as the document says"
          % (len(frames), len(seen)))


def test_frame_period_and_jitter():
    require_run()
    frames = candump_frames(RESULT.files["capture.log"])
    by_id = {}
    for t, _, can_id, _ in frames:
        by_id.setdefault(can_id, []).append(t)
    intervals = []
    for times in by_id.values():
        intervals += [(b - a) * 1000 for a, b in zip(times, times[1:])]
    check(intervals, "no intervals")
    intervals.sort()
    median = statistics.median(intervals)
    p99 = intervals[min(len(intervals) - 1, int(len(intervals) * 0.99))]
    expected = CAPTURE_S * 1000 / PERIOD_MS
    counts = [len(t) for t in by_id.values()]
    print("  period %d ms: median %.2f ms, p99 %.2f ms, max %.2f ms over %d intervals; "
          "%d-%d frames per id in %d s (%d expected)"
          % (PERIOD_MS, median, p99, intervals[-1], len(intervals), min(counts), max(counts),
             CAPTURE_S, expected))
    # The VM's CPU is emulated (TCG) on a shared machine. The mirror keeps
    # to a fixed schedule: a late period is followed by an early one, and a
    # period missed altogether is skipped, not sent in a burst.
    check(abs(median - PERIOD_MS) <= PERIOD_MS * 0.15, "median interval %.2f ms" % median)
    check(min(counts) >= expected * 0.7, "too few frames: %s" % counts)
    check(max(counts) <= expected * 1.1 + 1, "too many frames: %s" % counts)


def test_interface_down_up_deleted_created():
    import cantools
    require_run()
    db = cantools.database.load_file(DBC)
    sending = modbus_counters("sending")
    down = modbus_counters("down")
    up = modbus_counters("up")
    absent = modbus_counters("absent")
    again = modbus_counters("again")
    print("  Modbus during each phase (state, sent, dropped, errors): "
          + "; ".join("%s %d/%d/%d/%d" % (n, c["state"], c["sent"], c["dropped"], c["errors"])
                      for n, c in (("sending", sending), ("down", down), ("up", up),
                                   ("absent", absent), ("again", again))))
    check(sending["state"] == 1 and sending["errors"] == 0 and sending["dropped"] == 0,
          "before the outage: %s" % sending)
    check(down["state"] == 4 and down["errors"] > 0 and down["dropped"] > 0,
          "interface down: %s" % down)
    check(up["state"] == 1 and up["sent"] > down["sent"], "interface up again: %s" % up)
    check(absent["state"] == 5 and absent["errors"] > up["errors"],
          "interface deleted: %s" % absent)
    check(again["state"] == 1 and again["sent"] > absent["sent"],
          "interface created again: %s" % again)
    # Each change of state is logged once. Deleting an interface takes it
    # down first: the mirror may see that step too.
    log = RESULT.files["gw.log"]
    steps = [m for line in log.splitlines()
             for m in re.findall(r"CAN mirror: (?:vcan0: )?(sending|interface is down|"
                                 r"no such interface)", line)]
    check(re.fullmatch(r"S D S (D )?A S", " ".join(
              {"sending": "S", "interface is down": "D", "no such interface": "A"}[m]
              for m in steps)) is not None,
          "the mirror's log lines are not sending, down, sending, [down,] absent, "
          "sending:\n" + log)
    # The frames stop twice and resume twice; the receiver is told the loss.
    frames = [f for f in candump_frames(RESULT.files["outage.log"]) if f[1] == "vcan0"]
    gaps = [(a[0], b[0] - a[0]) for a, b in zip(frames, frames[1:]) if b[0] - a[0] > 0.5]
    check(len(gaps) == 2, "expected two gaps in the frames, got %s" % gaps)
    health = [v for t, n, v in decoded(db, frames) if n == "JAKA_Health"]
    check(health[0]["FramesDropped"] == 0 and health[-1]["FramesDropped"] > 0,
          "FramesDropped %s .. %s" % (health[0]["FramesDropped"], health[-1]["FramesDropped"]))
    print("  frames stopped for %s s and resumed each time"
          % " and ".join("%.2f" % g for _, g in gaps))


if __name__ == "__main__":
    vm.ensure_cantools(__file__)
    started = time.monotonic()
    try:
        run([test_vm_runs_gateway_and_simulator, test_every_frame_decodes_to_the_document,
             test_frame_period_and_jitter, test_interface_down_up_deleted_created])
    finally:
        print("CAN VM test wall time: %.1f s" % (time.monotonic() - started), file=sys.stderr)
