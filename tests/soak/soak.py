#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The chaos soak (make soak): jakasim, the sanitizer build of jakagw and a
PLC running the command recipe in a loop, under a random schedule of field
faults, in a private network namespace (unshare -n) with nftables.

    tests/soak/soak.py [SECONDS]     (make soak SOAK_S=600)
    JAKAGW_BIN_DIR=build-san         which build (make soak: build-san)
    SOAK_SEED=N                      the schedule's random seed (printed)
    SOAK_FAULTS="rst plc"            only these kinds (pull, rst, loss) or
                                     links (status, command, plc)

Faults, one at a time, each on one link (the status port, the command port,
or the PLC's connection: the PLC talks from 127.0.0.2, the monitor from
127.0.0.1): a silent pull (every packet dropped, no FIN, no RST) of both
directions or of one direction, an RST injected mid-stream (reject with tcp
reset of the gateway's packets on that link, for 1 s), and random loss of 1-10 % (numgen random).
After each, the links must come back within reconnect_max_ms plus a connect
(plus a slack for the sanitizer build).

The PLC (raw Modbus TCP, its socket closed abortively when a request times
out, as a PLC's stack should, so no old request reaches the gateway late)
feeds the heartbeat and runs power_on, enable_robot, load_program (a new
name each cycle), play_program, rapid_rate, pause_program, resume_program,
stop_program, and now and then disable_robot and power_off, one at a time
through the exactly-once mailbox. A monitor client reads the links, the
fault latch and the write owner every 50 ms, for the detection times.

Checked all along and at the end (each failure is a violation):
- every command the PLC wrote ends done, refused (by the robot or the
  gateway), not sent or outcome unknown;
- jakasim's own log of received commands agrees: a command done or refused
  by the robot was received exactly once, while it was in flight; one with
  an unknown outcome at most once, while in flight; one not sent (or refused
  by the gateway, or never accepted) never; none twice, none after the PLC
  read its result, none after a command-port reconnect that came after the
  PLC wrote it; nothing the PLC did not write (the network-exception action
  is "keep", so every program command the robot gets is the PLC's);
- the links recover after every fault;
- jakagw's descriptors return to their count at the start, its RSS stays
  flat over the second half; no sanitizer report from either process.
"""
import collections
import json
import os
import random
import re
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))

import harness  # noqa: E402
from harness import (Gateway, Sim, TestFailure, check, is_housekeeping,  # noqa: E402
                     mbap, open_fds, recv_adu, rss_kb, wait_until)

PLC_ADDR = "127.0.0.2"
RECONNECT_MAX_MS = 5000
RECOVERY_SLACK_S = 3.0
REQUEST_TIMEOUT_S = 1.5
HEARTBEAT_S = 0.1
TIME_LIMIT_MS = 1000

CONFIG = """[robot]
reconnect_max_ms = %d
[network_exception]
time_limit_ms = %d
action = keep
""" % (RECONNECT_MAX_MS, TIME_LIMIT_MS)

MAILBOX = {"power_on": 1, "power_off": 2, "enable_robot": 3, "disable_robot": 4,
           "load_program": 10, "play_program": 11, "pause_program": 12,
           "resume_program": 13, "stop_program": 14, "rapid_rate": 20}
H_HEARTBEAT, H_PROGRAM_NAME, H_MAILBOX = 0, 200, 400
C_FAULT_RESET = 130
I_MAILBOX_ACK, I_MAILBOX_DONE, I_MAILBOX_STATE = 4600, 4601, 4602


def log(text):
    print("[%7.1f] %s" % (time.monotonic() - T0, text), flush=True)


T0 = time.monotonic()


# ---- the namespace and nftables ----

def enter_namespace():
    """Runs this script again inside a new network namespace, loopback up."""
    if os.environ.get("JAKAGW_SOAK_NS") == "1":
        subprocess.run(["ip", "link", "set", "lo", "up"], check=True)
        subprocess.run(["ip", "addr", "add", "127.0.0.2/8", "dev", "lo"],
                       capture_output=True)
        return
    for tool in ("unshare", "nft", "ip"):
        check(subprocess.run(["sh", "-c", "command -v " + tool], capture_output=True)
              .returncode == 0, "%s is missing (make deps)" % tool)
    env = dict(os.environ, JAKAGW_SOAK_NS="1")
    os.execvpe("unshare", ["unshare", "-n", sys.executable, os.path.abspath(__file__)]
               + sys.argv[1:], env)


def nft(script):
    out = subprocess.run(["nft", "-f", "-"], input=script, text=True, capture_output=True)
    check(out.returncode == 0, "nft: %s\n%s" % (out.stderr.strip(), script))


def nft_setup():
    nft("add table inet soak\nflush table inet soak\n"
        "add chain inet soak out { type filter hook output priority 0; policy accept; }\n")


def nft_rules(rules):
    nft("flush chain inet soak out\n" + "".join("add rule inet soak out %s\n" % r for r in rules))


def nft_clear():
    nft("flush chain inet soak out\n")


class Link:
    """One link as nftables sees it: both directions ('to' the server,
    'from' it) by port, and for the PLC by the PLC's address."""

    def __init__(self, name, port, client=None):
        self.name, self.port, self.client = name, port, client

    def match(self, direction):
        if self.client:
            return {"to": "ip saddr %s tcp dport %d" % (self.client, self.port),
                    "from": "ip daddr %s tcp sport %d" % (self.client, self.port)}[direction]
        return {"to": "tcp dport %d" % self.port, "from": "tcp sport %d" % self.port}[direction]


# ---- the PLC, on raw sockets ----

class LinkLost(Exception):
    pass


class RawPlc:
    """A Modbus TCP master from PLC_ADDR. A request that times out closes
    the socket abortively (SO_LINGER 0) and raises LinkLost; the next
    request connects again."""

    def __init__(self, port, source):
        self.port, self.source = port, source
        self.sock = None
        self.tid = 0
        self.reconnects = 0
        self.errors = 0     # requests and connects that failed

    def _connect(self):
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        s.bind((self.source, 0))
        s.settimeout(REQUEST_TIMEOUT_S)
        try:
            s.connect(("127.0.0.1", self.port))
        except OSError as e:
            s.close()
            self.errors += 1
            raise LinkLost("connect: %s" % e)
        self.sock = s
        self.reconnects += 1

    def drop(self):
        if self.sock:
            self.sock.close()  # SO_LINGER 0: RST, nothing left queued
            self.sock = None

    def request(self, pdu):
        if self.sock is None:
            self._connect()
        self.tid = (self.tid + 1) & 0xFFFF
        try:
            self.sock.sendall(mbap(self.tid, pdu))
            while True:
                tid, _, reply = recv_adu(self.sock)
                if tid == self.tid:
                    return reply
        except (OSError, TestFailure) as e:
            self.drop()
            self.errors += 1
            raise LinkLost(str(e))

    def write_regs(self, address, values):
        pdu = struct.pack(">BHHB", 16, address, len(values), 2 * len(values)) + \
            struct.pack(">%dH" % len(values), *values)
        reply = self.request(pdu)
        return 0 if reply[0] == 16 else reply[1]

    def write_reg(self, address, value):
        reply = self.request(struct.pack(">BHH", 6, address, value))
        return 0 if reply[0] == 6 else reply[1]

    def write_coil(self, address, value):
        reply = self.request(struct.pack(">BHH", 5, address, 0xFF00 if value else 0))
        return 0 if reply[0] == 5 else reply[1]

    def ir(self, address, count=1):
        reply = self.request(struct.pack(">BHH", 4, address, count))
        if reply[0] != 4:
            raise LinkLost("exception %d reading input registers %d" % (reply[1], address))
        return list(struct.unpack(">%dH" % count, reply[2:]))

    def di(self, address, count=1):
        reply = self.request(struct.pack(">BHH", 2, address, count))
        if reply[0] != 2:
            raise LinkLost("exception %d reading discrete inputs" % reply[1])
        return [(reply[2 + i // 8] >> (i % 8)) & 1 for i in range(count)]


def f32_regs(value):
    return list(struct.unpack(">2H", struct.pack(">f", value)))


def text_regs(text, count):
    return list(struct.unpack(">%dH" % count, text.encode().ljust(2 * count, b"\0")))


# ---- the result states, from the register map's own description ----

def result_states():
    """{value: kind} from result_power_on_state's description: done, robot
    (refused by the robot), unknown (sent, no reply), not_sent, gateway
    (refused before sending), pending, idle."""
    rows = [r for r in harness.map_rows() if r["name"] == "result_power_on_state"]
    check(rows, "no result_power_on_state in the register map")
    kinds = {}
    text = rows[0]["description"].split(":", 1)[1]
    for m in re.finditer(r"(\d+) (.*?)(?=,? \d+ |, \d+|$)", text.strip()):
        number, name = m.group(1), m.group(2).lower()
        if "not sent" in name:
            kind = "not_sent"
        elif "unknown" in name or "timeout" in name or "link down" in name or "lost" in name:
            kind = "unknown"
        elif name.startswith("done"):
            kind = "done"
        elif "robot" in name:
            kind = "robot"
        elif "invalid" in name or "refused" in name:
            kind = "gateway"
        elif "pending" in name:
            kind = "pending"
        else:
            kind = "idle"
        kinds[int(number)] = kind
    return kinds


# ---- the soak ----

class Soak:
    def __init__(self, seconds, seed):
        self.seconds = seconds
        self.rng = random.Random(seed)           # the fault schedule
        self.plc_rng = random.Random(seed + 1)   # the PLC's pauses and values
        self.violations = []
        self.stop = threading.Event()
        self.commands = []          # dicts, in order
        self.faults = collections.Counter()
        self.detect = collections.defaultdict(list)
        self.undetected = collections.Counter()
        self.loss_trips = collections.Counter()
        self.recover = collections.defaultdict(list)
        self.samples = []           # (t, fds, rss)
        self.monitor_state = {}
        self.monitor_history = []   # (t, state)
        self.lock = threading.Lock()
        self.states = result_states()
        only = os.environ.get("SOAK_FAULTS", "").split()
        self.faults_chosen = [f for f in self.FAULTS if not only or f[0] in only or f[1] in only]
        check(self.faults_chosen, "SOAK_FAULTS=%s names no fault" % " ".join(only))
        self.plc = None

    def violation(self, text):
        log("VIOLATION: " + text)
        self.violations.append(text)

    # -- processes --

    def start(self):
        self.sim = Sim("--log-commands")
        self.gw = Gateway(self.sim, CONFIG)
        self.links = {"status": Link("status", self.sim.status_port),
                      "command": Link("command", self.sim.command_port),
                      "plc": Link("plc", self.gw.modbus_port, PLC_ADDR)}

    def sim_log(self):
        with open(self.sim.log.name, "rb") as f:
            return f.read()

    def sim_offset(self):
        return os.path.getsize(self.sim.log.name)

    # -- the monitor --

    def monitor(self):
        s = None
        while not self.stop.is_set():
            try:
                if s is None:
                    s = harness.raw_client(self.gw.modbus_port, timeout=2)
                di = harness.read_bits(s, 2, 0, 3)
                regs = harness.read_input_registers(s, 60, 7)
                owner = harness.read_input_registers(s, 66, 24)
                counts = harness.read_input_registers(s, 32, 4)
                state = {"status_link": di[0], "command_link": di[1], "fresh": di[2],
                         "fault": regs[0], "handle": regs[4], "owner": any(owner),
                         "status_reconnects": counts[0] << 16 | counts[1],
                         "command_reconnects": counts[2] << 16 | counts[3],
                         "plc_reconnects": self.plc.errors if self.plc else 0}
            except (OSError, TestFailure):
                if s:
                    s.close()
                s = None
                state = None
            now = time.monotonic()
            if state is not None:
                with self.lock:
                    if state != self.monitor_state:
                        self.monitor_history.append((now, state))
                    self.monitor_state = state
            time.sleep(0.05)
        if s:
            s.close()

    def healthy(self):
        st = self.monitor_state
        return (st.get("status_link") == 1 and st.get("command_link") == 1 and
                st.get("fresh") == 1 and st.get("handle") == 2 and st.get("owner") and
                st.get("fault") == 0)

    def first_after(self, t0, pred):
        with self.lock:
            for t, st in self.monitor_history:
                if t >= t0 and pred(st):
                    return t
        return None

    # -- the PLC --

    def plc_loop(self):
        plc = RawPlc(self.gw.modbus_port, PLC_ADDR)
        self.plc = plc
        beat = [0, 0.0]

        def heartbeat(force=False):
            now = time.monotonic()
            if force or now - beat[1] >= HEARTBEAT_S:
                beat[0] = (beat[0] + 1) & 0xFFFF
                plc.write_reg(H_HEARTBEAT, beat[0])
                beat[1] = now

        def pause(seconds):
            end = time.monotonic() + seconds
            while time.monotonic() < end and not self.stop.is_set():
                try:
                    heartbeat()
                except LinkLost:
                    time.sleep(0.2)
                time.sleep(0.02)

        seq = None
        cycle = 0
        while not self.stop.is_set():
            cycle += 1
            recipe = [("power_on", []), ("enable_robot", []),
                      ("load_program", ["soak_%05d" % cycle]), ("play_program", []),
                      ("rapid_rate", [round(self.plc_rng.uniform(0.2, 1.0), 3)]),
                      ("pause_program", []), ("resume_program", []), ("stop_program", [])]
            if cycle % 5 == 0:
                recipe += [("disable_robot", []), ("power_off", [])]
            for name, args in recipe:
                if self.stop.is_set():
                    break
                seq = self.run_command(plc, heartbeat, name, args, seq)
                pause(self.plc_rng.uniform(0.05, 0.4))
        plc.drop()

    def ready(self, plc, heartbeat):
        """Waits until the PLC is connected, owns the write side, sees the
        command link up and the robot's handler accepted, and has reset a
        latched fault; as a PLC checks before commanding."""
        while not self.stop.is_set():
            try:
                heartbeat()
                fault = plc.ir(60)[0]
                if fault:
                    plc.write_coil(C_FAULT_RESET, 1)
                    continue
                link = plc.di(1)[0]
                handle = plc.ir(64)[0]
                if link and handle == 2:
                    return True
            except LinkLost:
                time.sleep(0.2)
            time.sleep(0.05)
        return False

    def run_command(self, plc, heartbeat, name, args, seq):
        """One command through the mailbox, followed to its end."""
        if not self.ready(plc, heartbeat):
            return seq
        while seq is None and not self.stop.is_set():
            try:
                seq = plc.ir(I_MAILBOX_ACK)[0]
            except LinkLost:
                time.sleep(0.2)
        if seq is None:
            return seq
        seq = seq % 65535 + 1
        values = [MAILBOX[name]]
        if name == "load_program":
            # The name first, confirmed: a name write lost on the way would
            # load the previous cycle's program.
            try:
                if plc.write_regs(H_PROGRAM_NAME, text_regs(args[0], 32)) != 0:
                    return seq
            except LinkLost:
                return seq
            fargs = []
        else:
            fargs = args
        for a in fargs + [0.0] * (12 - len(fargs)):
            values += f32_regs(a)
        values.append(seq)
        cmd = {"name": name, "args": args, "seq": seq, "t_write": time.monotonic(),
               "offset_write": self.sim_offset()}
        self.commands.append(cmd)
        accepted = None
        try:
            code = plc.write_regs(H_MAILBOX, values)
            accepted = code == 0
            if not accepted:
                cmd["exception"] = code
        except LinkLost:
            pass
        # Find out what became of it; the PLC's link may be down meanwhile.
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                heartbeat()
                if accepted is None:
                    accepted = plc.ir(I_MAILBOX_ACK)[0] == seq
                    if not accepted:
                        cmd["exception"] = "never accepted (the PLC's link failed)"
                if not accepted:
                    cmd["kind"] = "gateway"
                    break
                done, state = plc.ir(I_MAILBOX_DONE, 2)
                if done == seq:
                    cmd["state"] = state
                    cmd["kind"] = self.states.get(state, "bad state %d" % state)
                    break
            except LinkLost:
                time.sleep(0.2)
            time.sleep(0.05)
        else:
            self.violation("%s (seq %d) never ended" % (name, seq))
            cmd["kind"] = "never ended"
        cmd["t_result"] = time.monotonic()
        cmd["offset_result"] = self.sim_offset()
        if cmd["kind"] not in ("done", "robot", "unknown", "not_sent", "gateway"):
            self.violation("%s (seq %d) ended in state %s" % (name, seq, cmd.get("state")))
        return seq

    # -- faults --

    FAULTS = [
        ("pull", "status", "both"), ("pull", "status", "to"), ("pull", "status", "from"),
        ("pull", "command", "both"), ("pull", "command", "to"), ("pull", "command", "from"),
        ("pull", "plc", "both"), ("pull", "plc", "to"), ("pull", "plc", "from"),
        ("rst", "status", "gateway"), ("rst", "command", "gateway"), ("rst", "plc", "gateway"),
        ("loss", "status", "both"), ("loss", "command", "both"), ("loss", "plc", "both"),
    ]

    def detected(self, link, st, before):
        """Whether monitor state 'st' shows the fault on 'link'; 'before'
        is the state when it was injected. An RST shows as a reconnect."""
        if st is None:
            return False
        key = link + "_reconnects"
        if before and key in before and st.get(key, 0) > before[key]:
            return True
        if link == "status":
            return st.get("fresh") == 0 or st.get("status_link") == 0
        if link == "command":
            return st.get("command_link") == 0
        return not st.get("owner")

    def inject(self, kind, link_name, direction):
        link = self.links[link_name]
        dirs = ["to", "from"] if direction == "both" else [direction]
        if kind == "pull":
            nft_rules(["%s drop" % link.match(d) for d in dirs])
            return "silent pull (%s)" % {"both": "both directions", "to": "to the server only",
                                         "from": "from the server only"}[direction]
        if kind == "rst":
            # The gateway's own packets are answered with an RST, so that
            # its socket is reset (the other side's would only reset the
            # peer, and the gateway would see silence).
            nft_rules(["%s reject with tcp reset" % link.match("from" if link.client else "to")])
            return "RST to the gateway mid-stream"
        percent = self.rng.randint(1, 10)
        nft_rules(["%s numgen random mod 100 < %d drop" % (link.match(d), percent)
                   for d in dirs])
        return "random loss %d%%" % percent

    def schedule(self):
        end = T0 + self.seconds
        self.wait_healthy(60, "the start")
        while time.monotonic() < end - 20 and not self.stop.is_set():
            kind, link, direction = self.rng.choice(self.faults_chosen)
            duration = {"pull": self.rng.uniform(2, 8), "rst": 1.0,
                        "loss": self.rng.uniform(5, 15)}[kind]
            label = "%s %s" % (link, kind if kind != "pull" else "pull " + direction)
            t0 = time.monotonic()
            before = dict(self.monitor_state)
            what = self.inject(kind, link, direction)
            self.faults[label] += 1
            log("fault: %s port, %s, %.1f s" % (link, what, duration))
            time.sleep(duration)
            nft_clear()
            t_restore = time.monotonic()
            if kind == "loss":
                # Not a fault the gateway should act on: whether the link
                # read down or stale all the same is counted, not judged.
                t = self.first_after(t0, lambda st: self.detected(link, st, before))
                if t is not None and t <= t_restore:
                    self.loss_trips[label] += 1
            else:
                t = self.first_after(t0, lambda st: self.detected(link, st, before))
                late = 2.0 if kind == "rst" else 0.2
                if t is not None and t <= t_restore + late:
                    self.detect[label].append(t - t0)
                else:
                    self.undetected[label] += 1
            # Recovery: every link up, the handler accepted, the PLC the owner.
            bound = RECONNECT_MAX_MS / 1000 + 1 + RECOVERY_SLACK_S
            t = self.wait_healthy(bound, "recovery after %s" % label)
            if t is not None:
                self.recover[label].append(t - t_restore)
            self.sample()
            time.sleep(self.rng.uniform(1, 3))

    def wait_healthy(self, bound, what):
        start = time.monotonic()
        while time.monotonic() - start < bound:
            # The PLC resets a latched fault as soon as it can write again.
            if self.healthy():
                return time.monotonic()
            time.sleep(0.05)
        self.violation("%s: not healthy within %.1f s: %s" % (what, bound, self.monitor_state))
        # Keep going once it is healthy again, to find more.
        while not self.healthy() and not self.stop.is_set():
            time.sleep(0.1)
        return None

    def sample(self):
        self.samples.append((time.monotonic() - T0, open_fds(self.gw.proc.pid),
                             rss_kb(self.gw.proc.pid)))

    # -- the check against the robot's log --

    def check_robot_log(self):
        text = self.sim_log()
        decoder = json.JSONDecoder()
        receipts = []   # (offset, name, request)
        connects = []
        pos = 0
        for line in text.split(b"\n"):
            start = pos
            pos += len(line) + 1
            s = line.decode(errors="replace")
            if "jakasim: command client connected" in s:
                connects.append(start)
                continue
            at = s.find(harness.SIM_COMMAND_MARK + "{")
            if at < 0:
                continue
            try:
                req, _ = decoder.raw_decode(s[at + len(harness.SIM_COMMAND_MARK):])
                name = req.get("cmdName")
            except (ValueError, AttributeError):
                self.violation("jakasim logged a request it could not parse: %s" % s[:200])
                continue
            if is_housekeeping(name):
                continue
            receipts.append((start, name, req))
        used = set()
        for cmd in self.commands:
            if "offset_result" not in cmd:
                continue
            lo, hi = cmd["offset_write"], cmd["offset_result"]
            mine = [i for i, r in enumerate(receipts) if lo <= r[0] < hi]
            for i in mine:
                used.add(i)
            same = [receipts[i] for i in mine if receipts[i][1] == cmd["name"]]
            other = [receipts[i] for i in mine if receipts[i][1] != cmd["name"]]
            label = "%s seq %d (%s)" % (cmd["name"], cmd["seq"], cmd["kind"])
            if other:
                self.violation("%s: the robot received %s while it was in flight"
                               % (label, [r[1] for r in other]))
            if cmd["name"] == "load_program":
                for r in same:
                    if r[2].get("programName") != cmd["args"][0]:
                        self.violation("%s: the robot loaded %s" % (label, r[2]))
            kind = cmd["kind"]
            want = {"done": (1, 1), "robot": (1, 1), "unknown": (0, 1),
                    "not_sent": (0, 0), "gateway": (0, 0)}.get(kind, (0, 1))
            if not want[0] <= len(same) <= want[1]:
                self.violation("%s: received %d times (expected %d..%d)"
                               % (label, len(same), want[0], want[1]))
            for r in same:
                later = [c for c in connects if lo <= c < r[0]]
                if later:
                    self.violation("%s: received after a command-port reconnect that "
                                   "followed its write" % label)
        for i, r in enumerate(receipts):
            if i not in used:
                near = [(c["name"], c["seq"], c.get("kind"), c.get("state"),
                         c.get("exception"), c["offset_write"], c.get("offset_result"),
                         round(c.get("t_result", 0) - c["t_write"], 2)) for c in self.commands
                        if abs(c["offset_write"] - r[0]) < 3000]
                self.violation("the robot received %s with no PLC command in flight (late, "
                               "or after its result): %s at log offset %d; PLC commands "
                               "near it: %s" % (r[1], json.dumps(r[2])[:120], r[0], near))
        return len(receipts)

    # -- the run --

    def run(self):
        nft_setup()
        self.start()
        threads = [threading.Thread(target=self.monitor, daemon=True),
                   threading.Thread(target=self.plc_loop, daemon=True)]
        for t in threads:
            t.start()
        time.sleep(2)
        self.sample()
        try:
            self.schedule()
            # The last stretch without faults, then everything must settle.
            nft_clear()
            time.sleep(max(0, T0 + self.seconds - time.monotonic()))
        finally:
            self.stop.set()
            for t in threads:
                t.join(timeout=30)
        nft_clear()
        fds_start = self.samples[0][1]
        try:
            wait_until(lambda: open_fds(self.gw.proc.pid) <= fds_start + 1, 70,
                       "jakagw's descriptors back to %d" % fds_start)
        except TestFailure as e:
            self.violation(str(e) + " (now %d)" % open_fds(self.gw.proc.pid))
        self.sample()
        received = self.check_robot_log()
        for proc in (self.gw, self.sim):
            try:
                proc.stop()
            except TestFailure as e:
                self.violation(str(e)[:3000])
        self.report(received)

    def report(self, received):
        kinds = collections.Counter(c.get("kind") for c in self.commands)
        print()
        print("soak: %.0f s, seed %s, %s" % (time.monotonic() - T0, SEED, harness.JAKAGW))
        print("faults injected: %d" % sum(self.faults.values()))
        print("commands: %d written (%s); the robot received %d"
              % (len(self.commands), ", ".join("%s %d" % kv for kv in sorted(kinds.items())),
                 received))
        print("PLC reconnects: %d" % self.plc.reconnects)
        print("%-28s %6s %22s %10s %22s" % ("fault", "count", "detection median/max",
                                           "undetected", "recovery median/max"))
        for label in sorted(self.faults):
            d, r = self.detect.get(label, []), self.recover.get(label, [])
            print("%-28s %6d %22s %10s %22s" % (
                label, self.faults[label],
                "%.2f / %.2f s" % (statistics.median(d), max(d)) if d else
                "read down/stale %d" % self.loss_trips[label] if "loss" in label else "-",
                self.undetected[label] if "loss" not in label else "",
                "%.2f / %.2f s" % (statistics.median(r), max(r)) if r else "-"))
        fds = [s[1] for s in self.samples]
        rss = [s[2] for s in self.samples]
        half = rss[len(rss) // 2:]
        print("jakagw descriptors: start %d, end %d (min %d, max %d)"
              % (fds[0], fds[-1], min(fds), max(fds)))
        print("jakagw RSS: start %d KiB, half-way %d KiB, end %d KiB"
              % (rss[0], half[0], rss[-1]))
        if len(half) >= 2 and rss[-1] > half[0] * 1.10 + 1024:
            self.violation("RSS grew over the second half: %d -> %d KiB" % (half[0], rss[-1]))
        print("violations: %d" % len(self.violations))
        for v in self.violations[:20]:
            print("  " + v)


SEED = None


def main():
    global SEED, T0
    enter_namespace()
    # A smaller quarantine than ASan's 256 MiB, so that the gateway's RSS
    # levels off in the first minute and growth after that is the gateway's.
    asan = os.environ.get("ASAN_OPTIONS", "detect_leaks=1")
    if "quarantine_size_mb" not in asan:
        os.environ["ASAN_OPTIONS"] = asan + ":quarantine_size_mb=16"
    seconds = float(sys.argv[1]) if len(sys.argv) > 1 else float(os.environ.get("SOAK_S", 600))
    SEED = int(os.environ.get("SOAK_SEED", int(time.time())))
    T0 = time.monotonic()
    soak = Soak(seconds, SEED)
    soak.run()
    sys.exit(1 if soak.violations else 0)


if __name__ == "__main__":
    main()
