#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The PLC model: docs/plc-guide.md's recipes run as a PLC runs them, a
state machine on one Modbus connection (pymodbus), against the real jakasim
and jakagw, with faults generated at random points.

Each run starts from a ready cell (heartbeat running, motion enable 1, no
fault, the robot powered and enabled), runs one to three recipes (a joint
move, absolute or relative; a moveL written as its whole block; a move
through the exactly-once mailbox; an output; a program started and
stopped) and injects at most one fault at a random PLC scan: the heartbeat
stops, motion enable drops, the PLC's connection drops and comes back, the
PLC restarts (its connection gone, silent, then its start-up recipe with
the trigger it held at 1), an emergency stop, the command link to the
robot is cut (a TCP relay between the gateway and jakasim's command port,
closed with an RST), motion enable dropped with the reset pressed at once
(refused, 06, while the reaction is judged or the arm moves), or a second
program on the PLC's host writes the heartbeat and a move trigger (both
refused, 01). Each cell's jakasim brakes (--stop-time-ms 100, 300, 600 or
1000). Then it recovers as the guide says (the reset once IR 5602 no
longer reads 2 or 5) and checks, on every run:

- after a fault that the gateway reacts to, the arm (seen on jakasim's own
  status port, not through the gateway) is stopped within time_limit_ms +
  one status period + the reply time + the cell's stopping time, plus one
  status period and a reply more when the gateway escalated (a pause the
  arm did not brake on, then stop_program) (plus scheduling slack on a
  shared machine, printed with the figures measured), an early reset or
  not;
- a recipe step passes only on its own request's result: the result count
  moved by exactly one from the value read before the trigger, and a
  "done" is backed by the robot's log (the command received after the
  trigger); a move is done only when the motion count moved on and the
  motion state reads 2, with the arm at the written target;
- no command reaches the robot twice (jakasim --log-commands: every target
  is new, every other command at most as often as the PLC wrote it);
- every move the robot received carries a target the PLC wrote.

Three faults come at a chosen moment instead, each in a cell of its own,
side by side (test_plc_model_faults_at_chosen_moments): motion enable
dropped while a joint_move waits in the gateway's queue behind a setpoint
the robot answers late (the move's own result 8, nothing moves, the move
triggered again after the reset arrives); the gateway's queue full (a
move refused 06 with its own result 7 "busy", the stop done and at the
robot ahead of the queue); a stop the robot refuses while a move runs
(the motion state stays 1 while the arm goes on, the second stop ends
it: 3 once the arm stands still).

Several cells (a jakasim, a relay and a jakagw each) run side by side, one
PLC thread each. PLC_MODEL_RUNS (default 200; tests/run.sh gives the
sanitizer build fewer), PLC_MODEL_SEED (printed; repeats the schedule of
faults and recipes, not the machine's timing), PLC_MODEL_CELLS (default 6).
"""
import collections
import json
import os
import random
import signal
import socket
import struct
import threading
import time

from harness import Gateway, Sim, check, map_rows, run, text_registers, wait_until

ROWS = {}
for _row in map_rows():
    ROWS.setdefault((_row["table"], _row["name"]), int(_row["address"]))


def ir(name):
    return ROWS[("input_register", name)]


def coil(name):
    return ROWS[("coil", name)]


def hr(name):
    return ROWS[("holding_register", name)]


def di(name):
    return ROWS[("discrete_input", name)]


# The addresses the guide's recipes use, from the map.
MAGIC, WORD_ORDER, PROBE_F32 = ir("map_magic"), ir("word_order"), ir("probe_f32")
FAULT, REACTION, ROBOT_HANDLE = ir("fault"), ir("fault_reaction"), ir("robot_handle")
BEAT_STATE = ir("plc_heartbeat_state")
MOTION_STATE, MOTION_COUNT = ir("motion_state"), ir("motion_count")
INTERP_STATE = ir("interp_state")
HEARTBEAT = hr("plc_heartbeat")
PROGRAM_NAME = hr("load_program_name")
JOINT_TARGET, MOVEL_TARGET = hr("joint_move_joint_1"), hr("movel_pose_1")
MOVEL_LAST = hr("movel_tol") + 1  # the block ends with tol's second register
MAILBOX_CODE = hr("mailbox_code")
MAILBOX_ACK, MAILBOX_DONE, MAILBOX_STATE, MAILBOX_COUNT = ir("mailbox_ack_seq"), \
    ir("mailbox_done_seq"), ir("mailbox_state"), ir("mailbox_count")
FAULT_RESET, MOTION_ENABLE = coil("fault_reset"), coil("motion_enable")
OUTPUT, OUTPUT_BACK = coil("cabinet_do_1"), di("dout_1")
STATUS_FRESH, ENABLED, POWERED = di("status_fresh"), di("enabled"), di("powered_on")
INPOS = di("inpos")

PENDING, DONE = 1, 2
MOVING, ARRIVED = 1, 2  # motion states; 3 stopped short, 4 not in time
MAILBOX_JOINT_MOVE = 30

# Short runs: a small time_limit_ms, a fast status push.
LIMIT_MS = 200
PERIOD_MS = 20
REPLY_MS = 50  # jakasim answers at once; the loopback and the queue
# The machine runs other builds on 2 shared cores: slack for scheduling,
# on top of the bound the issue states.
SLACK_MS = int(os.environ.get("PLC_MODEL_SLACK_MS", "300"))
STOP_BOUND_S = (LIMIT_MS + PERIOD_MS + REPLY_MS + SLACK_MS) / 1000
# The one escalation the gateway may make (a second action one status
# period and a reply after the first's reply), with its own scheduling
# slack: the second action is a second trip through the same loop.
ESCALATION_S = (PERIOD_MS + REPLY_MS + SLACK_MS / 2) / 1000
SCAN_S = 0.01  # the PLC's cycle
HOME = [0.0, 90.0, 90.0, 0.0, 90.0, 0.0]
# Moves of up to half a second, so that a fault finds the arm moving when
# the gateway has to act (time_limit_ms after the last heartbeat).
JOINT_SPEED = 30.0

# The robot's own handler (set by the gateway on each command connection)
# acts ROBOT_LIMIT_MS after that connection is lost, even when the gateway
# has reconnected: a cut command link pauses a move that long after.
ROBOT_LIMIT_MS = 300
CONFIG = ("[robot]\nreconnect_min_ms = 50\nreconnect_max_ms = 200\n"
          "[commands]\nmotion = true\n"
          "[network_exception]\ntime_limit_ms = %d\nmotion_enable = true\n"
          "robot_time_limit_ms = %d\n" % (LIMIT_MS, ROBOT_LIMIT_MS))

# The chosen-moment cases inject their own faults: a heartbeat that lapses
# for a moment on a loaded machine must not add one (the policy's stop
# would take the refusal jakasim holds for the PLC's first stop).
CHOSEN_LIMIT_MS = 1000
CHOSEN_CONFIG = CONFIG.replace("time_limit_ms = %d\n" % LIMIT_MS,
                               "time_limit_ms = %d\n" % CHOSEN_LIMIT_MS)
assert CHOSEN_CONFIG != CONFIG

FAULTS = ("none", "heartbeat", "motion_enable", "reconnect", "plc_restart", "estop",
          "command_link", "early_reset", "second_program")
# Faults the gateway itself must answer by stopping the arm.
STOPPING = ("heartbeat", "motion_enable", "plc_restart", "estop", "early_reset")
# jakasim --stop-time-ms of the cells: each brakes as a real arm does.
STOP_TIMES_MS = (100, 300, 600, 1000)


def f32(value):
    """'value' as the f32 the registers carry."""
    return struct.unpack(">f", struct.pack(">f", value))[0]


def f32_registers(values):
    out = []
    for v in values:
        out += struct.unpack(">HH", struct.pack(">f", v))
    return out


def registers_f32(regs):
    return [struct.unpack(">f", struct.pack(">HH", regs[i], regs[i + 1]))[0]
            for i in range(0, len(regs), 2)]


class Violation(Exception):
    pass


class PlcGone(Exception):
    """The PLC's connection failed: the scan ends, the PLC reconnects."""


# ---- the robot's side: its command log and its own status stream ----

class RobotLog:
    """jakasim --log-commands, read as it grows: every command received,
    with the time it was read."""

    MARK = "jakasim: command "

    def __init__(self, sim):
        self.path = sim.log.name
        self.offset = 0
        self.partial = ""
        self.entries = []  # (cmdName, request dict)
        self.decoder = json.JSONDecoder()

    def poll(self):
        with open(self.path, errors="replace") as f:
            f.seek(self.offset)
            data = f.read()
            self.offset = f.tell()
        lines = (self.partial + data).split("\n")
        self.partial = lines.pop()
        for line in lines:
            at = line.find(self.MARK)
            if at < 0 or not line[at + len(self.MARK):].startswith("{"):
                continue
            try:
                req, _ = self.decoder.raw_decode(line[at + len(self.MARK):])
            except ValueError:
                continue
            if isinstance(req, dict):
                self.entries.append((req.get("cmdName"), req))
        return len(self.entries)

    def since(self, mark, name=None):
        self.poll()
        return [r for n, r in self.entries[mark:] if name is None or n == name]


class StatusWatch(threading.Thread):
    """jakasim's status port, read directly: when the arm moved, as the
    robot says it, with no gateway in between."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.port = port
        self.docs = collections.deque(maxlen=2000)  # (time, joints, estop)
        self.stopping = False
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=2)
        self.start()

    def run(self):
        buf = b""
        while not self.stopping:
            try:
                chunk = self.sock.recv(65536)
            except OSError:
                break
            if not chunk:
                break
            buf += chunk
            while True:
                start = buf.find(b'{"len": ')
                comma = buf.find(b",", start) if start >= 0 else -1
                if comma < 0:
                    break
                n = int(buf[start + 8:comma])
                if len(buf) < start + n:
                    break
                doc = json.loads(buf[start:start + n])
                buf = buf[start + n:]
                self.docs.append((time.monotonic(), doc["joint_actual_position"][:6],
                                  doc.get("emergency_stop")))

    def close(self):
        self.stopping = True
        self.sock.close()

    def snapshot(self, since=0.0):
        return [d for d in list(self.docs) if d[0] >= since]

    def joints(self):
        return self.docs[-1][1] if self.docs else None

    def moving_at(self, t):
        """Whether the arm moved across the documents around 't'."""
        docs = [d for d in list(self.docs) if t - 0.1 <= d[0] <= t + 0.05]
        return any(moved(a[1], b[1]) for a, b in zip(docs, docs[1:]))

    def stopped_since(self, t0, until):
        """The time of the first document after t0 from which the arm no
        longer moved up to 'until', or None if it moved at the end."""
        docs = [d for d in list(self.docs) if t0 <= d[0] <= until]
        if len(docs) < 2:
            return None
        still = docs[-1]
        for d in reversed(docs[:-1]):
            if moved(d[1], still[1]):
                break
            still = d
        if moved(docs[-2][1], docs[-1][1]):
            return None
        return still[0]


def moved(a, b, eps=1e-4):
    return any(abs(x - y) > eps for x, y in zip(a, b))


class Relay:
    """A TCP relay in front of jakasim's command port: the gateway's
    command link runs through it, and cut() closes it with an RST both
    ways, as a pulled cable that the gateway then sees reset."""

    def __init__(self, target_port):
        self.target = target_port
        self.listener = socket.socket()
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.listener.bind(("127.0.0.1", 0))
        self.listener.listen(8)
        self.port = self.listener.getsockname()[1]
        self.pairs = []
        self.lock = threading.Lock()
        self.closing = False
        threading.Thread(target=self.accept, daemon=True).start()

    def accept(self):
        while not self.closing:
            try:
                a, _ = self.listener.accept()
                b = socket.create_connection(("127.0.0.1", self.target), timeout=2)
            except OSError:
                if self.closing:
                    return
                continue
            for s in (a, b):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                s.settimeout(None)
            with self.lock:
                self.pairs.append((a, b))
            threading.Thread(target=self.pump, args=(a, b), daemon=True).start()
            threading.Thread(target=self.pump, args=(b, a), daemon=True).start()

    @staticmethod
    def pump(src, dst):
        try:
            while True:
                data = src.recv(65536)
                if not data:
                    break
                dst.sendall(data)
        except OSError:
            pass
        for s in (src, dst):
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    def cut(self):
        with self.lock:
            pairs, self.pairs = self.pairs, []
        for pair in pairs:
            for s in pair:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                s.close()

    def close(self):
        self.closing = True
        self.listener.close()
        self.cut()


class Ports:
    """Where the gateway finds the robot: jakasim's status port, the
    relay's command port."""

    def __init__(self, status_port, command_port):
        self.status_port, self.command_port = status_port, command_port


# ---- the PLC ----

class Plc:
    """One PLC on one Modbus connection: every request goes through scan(),
    which writes the heartbeat first, as a cyclic program does, unless the
    heartbeat fault holds it."""

    def __init__(self, cell):
        self.cell = cell
        self.port = cell.gw.modbus_port
        self.client = None
        self.beat = 0
        self.beating = True
        self.connect()

    def connect(self):
        from pymodbus.client import ModbusTcpClient
        if self.client:
            self.client.close()
        self.client = ModbusTcpClient("127.0.0.1", port=self.port, timeout=2, retries=0)
        if not self.client.connect():
            raise PlcGone("connect")

    def close(self):
        if self.client:
            self.client.close()
            self.client = None

    def call(self, what, *args):
        from pymodbus.pdu import ExceptionResponse
        if self.client is None:
            raise PlcGone("not connected")
        try:
            rr = getattr(self.client, what)(*args, slave=1)
        except Exception as e:  # a dropped connection, a timeout
            raise PlcGone("%s: %s" % (what, e))
        if isinstance(rr, ExceptionResponse):
            return rr
        if rr.isError():
            raise PlcGone("%s: %s" % (what, rr))
        return rr

    def scan(self):
        """One PLC cycle's bookkeeping: the heartbeat, then the fault
        schedule (which may act on this scan)."""
        self.cell.tick()
        if self.beating:
            self.beat = (self.beat + 1) & 0xFFFF
            self.write_reg(HEARTBEAT, self.beat)
            now = time.monotonic()
            # A PLC thread held up on the shared machine longer than the
            # limit has lost its heartbeat for real: the gateway is right
            # to react, and the run says so instead of failing.
            if self.cell.last_beat and now - self.cell.last_beat > LIMIT_MS / 1000 * 0.8:
                self.cell.plc_late = True
            self.cell.last_beat = now

    def ir(self, address, count=1):
        return self.call("read_input_registers", address, count).registers

    def di(self, address):
        return int(self.call("read_discrete_inputs", address, 1).bits[0])

    def write_coil(self, address, value):
        rr = self.call("write_coil", address, bool(value))
        return getattr(rr, "exception_code", 0)

    def write_reg(self, address, value):
        rr = self.call("write_register", address, value)
        return getattr(rr, "exception_code", 0)

    def write_regs(self, address, values):
        rr = self.call("write_registers", address, values)
        return getattr(rr, "exception_code", 0)

    def read_coil(self, address):
        return int(self.call("read_coils", address, 1).bits[0])

    def wait_for(self, read, accept, timeout, what):
        """Scans until accept(read()): returns the value read."""
        box = []

        def cond():
            box[:] = [read()]
            return accept(box[0])
        self.wait(cond, timeout, what)
        return box[0]

    def wait(self, cond, timeout, what):
        """Scans until cond() holds: the recipe's wait with its timeout."""
        deadline = time.monotonic() + timeout
        while True:
            self.scan()
            value = cond()
            if value:
                return value
            if time.monotonic() > deadline:
                raise StepFailed("timeout: " + what)
            time.sleep(SCAN_S)


class StepFailed(Exception):
    """A recipe step ended in its error branch (the PLC's Error output)."""


# ---- a cell: jakasim, the relay, jakagw, the PLC, the robot's side ----

class Cell:
    def __init__(self, index, rng, figures, events, sim_args=(), config=CONFIG):
        self.index = index
        self.rng = rng
        self.figures = figures
        # A robot that brakes: a stop from full speed takes 0.1-1 s.
        self.stop_ms = rng.choice(STOP_TIMES_MS)
        self.stop_bound_s = STOP_BOUND_S + self.stop_ms / 1000
        self.sim = Sim("--log-commands", "--period-ms", str(PERIOD_MS),
                       "--stop-time-ms", str(self.stop_ms), *sim_args)
        self.relay = Relay(self.sim.command_port)
        self.gw = Gateway(Ports(self.sim.status_port, self.relay.port), config)
        self.log = RobotLog(self.sim)
        self.watch = StatusWatch(self.sim.status_port)
        self.plc = None
        self.written_targets = []  # (kind, relative, values) the PLC wrote
        self.plc_writes = collections.Counter()  # triggers written with 1, per command
        self.fault_at = None  # scan index
        self.fault = "none"
        self.fault_time = None
        self.scans = 0
        self.last_beat = 0.0
        self.plc_late = False
        self.at_trigger = False
        self.trace = []
        self.events = events

    def close(self):
        try:
            if self.plc:
                self.plc.close()
            self.watch.close()
            self.relay.close()
        finally:
            try:
                self.gw.stop()
            finally:
                self.sim.stop()

    # -- faults --

    def tick(self):
        self.scans += 1
        if self.fault_at is not None and self.scans >= self.fault_at:
            self.fault_at = None
            self.inject()

    def after_trigger(self):
        """A drop or a restart scheduled for the middle of a handshake: the
        trigger written 1, its 0 not yet."""
        if self.at_trigger and self.fault_at is not None:
            self.fault_at = None
            self.events["%s right after a trigger's 1" % self.fault] += 1
            self.inject()

    def inject(self):
        kind = self.fault
        self.fault_time = time.monotonic()
        self.fault_log_mark = self.log.poll()
        self.trace.append("fault %s at scan %d" % (kind, self.scans))
        plc = self.plc
        if kind == "heartbeat":
            plc.beating = False
            self.fault_time = self.last_beat
        elif kind == "motion_enable":
            code = plc.write_coil(MOTION_ENABLE, 0)
            check(code == 0, "motion enable 0 refused with %02X" % code)
            self.fault_time = time.monotonic()
        elif kind == "reconnect":
            plc.close()
            time.sleep(self.rng.uniform(0, 0.1))  # well within time_limit_ms
            plc.connect()
        elif kind == "plc_restart":
            plc.close()
            self.fault_time = self.last_beat
            raise PlcRestart()
        elif kind == "estop":
            self.press_estop(True)
        elif kind == "command_link":
            self.relay.cut()
        elif kind == "early_reset":
            # Motion enable dropped, and the reset pressed as soon as the
            # fault shows: refused while the reaction is judged or the arm
            # moves (06), so it never cancels a stop (the bound holds).
            code = plc.write_coil(MOTION_ENABLE, 0)
            check(code == 0, "motion enable 0 refused with %02X" % code)
            self.fault_time = time.monotonic()
            code = plc.write_coil(FAULT_RESET, 1)
            self.events["early reset answered %02X" % code] += 1
            check(code in (0, 6), "the early reset answered %02X" % code)
        elif kind == "second_program":
            # Another program on the PLC's host (an HMI): it can neither
            # feed the heartbeat nor start motion (owner = connection).
            from pymodbus.client import ModbusTcpClient
            other = ModbusTcpClient("127.0.0.1", port=self.gw.modbus_port, timeout=2,
                                    retries=0)
            try:
                check(other.connect(), "the second program cannot connect")
                beat = other.write_register(HEARTBEAT, 4242, slave=1)
                move = other.write_coil(TRIGGERS["joint_move"], True, slave=1)
                codes = [getattr(r, "exception_code", 0) for r in (beat, move)]
                check(codes == [1, 1], "the second program's heartbeat and trigger: %s" % codes)
                self.events["second program refused"] += 1
            finally:
                other.close()

    # -- the robot's side --

    def press_estop(self, pressed):
        """jakasim's emergency stop (SIGRTMIN toggles it), pressed or
        released as its own status shows it."""
        if bool(self.watch.docs and self.watch.docs[-1][2]) != pressed:
            self.sim.proc.send_signal(signal.SIGRTMIN)
        wait_until(lambda: self.watch.docs and bool(self.watch.docs[-1][2]) == pressed, 2,
                   "the emergency stop %s" % ("pressed" if pressed else "released"))

    def mark(self):
        return self.log.poll()


class PlcRestart(Exception):
    pass


# ---- the guide's recipes ----

def startup(cell):
    """Start-up: connect, check the map, start the heartbeat, motion
    enable, reset a latched fault, power on and enable."""
    plc = cell.plc
    plc.beating = True
    check(plc.ir(MAGIC)[0] == 0x4A4B, "map magic")
    check(plc.ir(WORD_ORDER)[0] == 0 and
          abs(registers_f32(plc.ir(PROBE_F32, 2))[0] + 1234.5) < 1e-3, "word order")
    plc.wait(lambda: plc.ir(ROBOT_HANDLE)[0] == 2, 5, "the robot's handler accepted")
    plc.wait(lambda: plc.ir(BEAT_STATE)[0] == 1, 2, "the heartbeat seen running")
    check(plc.write_coil(MOTION_ENABLE, 1) == 0, "motion enable")
    # Every trigger 0, in one FC15 each run of coils.
    first = min(TRIGGERS.values())
    check(plc.call("write_coils", first, [False] * (max(TRIGGERS.values()) - first + 1))
          .function_code < 0x80, "the triggers 0")
    plc.wait(lambda: plc.di(STATUS_FRESH) == 1, 5, "status fresh")
    if plc.ir(FAULT)[0] != 0:
        fault_reset(cell)
    if not plc.di(POWERED):
        command(cell, "power_on")
        plc.wait(lambda: plc.di(POWERED), 2, "powered on")
    if not plc.di(ENABLED):
        command(cell, "enable_robot")
        plc.wait(lambda: plc.di(ENABLED), 2, "enabled")
    # What the robot does is not known after a fault or a restart: stop it.
    if plc.ir(INTERP_STATE)[0] != 0 or plc.ir(MOTION_STATE)[0] == MOVING:
        command(cell, "stop_program")
        plc.wait(lambda: plc.ir(INTERP_STATE)[0] == 0 and plc.ir(MOTION_STATE)[0] != MOVING,
                 2, "the robot stopped")


def retained_triggers(cell):
    """A restarted PLC whose output image kept its triggers writes them
    again as they were: a trigger still at 1 gets 1 from this new
    connection, which the gateway refuses (01) with the count moved, and
    the robot receives nothing."""
    plc = cell.plc
    for name, address in TRIGGERS.items():
        if not plc.read_coil(address):
            continue
        count_at = ir("result_%s_count" % name)
        before = plc.ir(count_at)[0]
        mark = cell.mark()
        code = plc.write_coil(address, 1)
        after = plc.ir(count_at)[0]
        cell.trace.append("retained %s = 1: exception %02X, count %d -> %d"
                          % (name, code, before, after))
        cell.events["trigger left at 1, written 1 again: refused"] += 1
        if code != 0x01 or (after - before) & 0xFFFF != 1:
            raise Violation("%s left at 1, written 1 by the restarted PLC: exception %02X, "
                            "count %d -> %d" % (name, code, before, after))
        time.sleep(0.05)
        if cell.log.since(mark, name):
            raise Violation("%s left at 1 and written 1 again reached the robot" % name)


def fault_reset(cell):
    """Fault reset: with the signal restored, the reaction judged (IR 5602
    not 2 or 5) and the arm stopped, coil 130 = 1 (06 while the arm still
    moves: again), then read IR 60 = 0."""
    plc = cell.plc
    plc.wait(lambda: plc.ir(REACTION)[0] not in (2, 5), 3, "the reaction judged")
    code = plc.wait_for(lambda: plc.write_coil(FAULT_RESET, 1), lambda c: c != 6, 3,
                        "the reset accepted")
    check(code == 0, "fault reset refused with %02X" % code)
    plc.wait(lambda: plc.ir(FAULT)[0] == 0, 2, "the fault cleared")


TRIGGERS = {name[4:]: coil(name) for (table, name) in ROWS
            if table == "coil" and name.startswith("cmd_")}


def command(cell, name, params=None):
    """The command handshake: read the result count, write the parameters
    in one FC16, trigger 0 -> 1, wait for the count to change, wait for the
    state to leave pending, read it, write 0. Returns the state; raises
    StepFailed on an exception or a timeout."""
    plc = cell.plc
    base = ir("result_%s_state" % name)
    count_at = ir("result_%s_count" % name)
    before = plc.ir(count_at)[0]
    if params:
        address, values = params
        code = plc.write_regs(address, values)
        if code:
            raise StepFailed("%s parameters refused with %02X" % (name, code))
    mark = cell.mark()
    trigger = TRIGGERS[name]
    if plc.read_coil(trigger):
        plc.write_coil(trigger, 0)
    cell.plc_writes[name] += 1
    code = plc.write_coil(trigger, 1)
    try:
        cell.after_trigger()
        now = plc.wait_for(lambda: plc.ir(count_at)[0], lambda v: v != before, 1,
                           name + "'s count")
        if (now - before) & 0xFFFF != 1:
            raise Violation("%s: the count moved from %d to %d for one trigger"
                            % (name, before, now))
        if code:
            raise StepFailed("%s refused with %02X: %s" % (name, code, text(plc, base + 3)))
        state = plc.wait_for(lambda: plc.ir(base)[0], lambda v: v != PENDING, 3,
                             name + "'s result")
    finally:
        try:
            plc.write_coil(trigger, 0)
        except PlcGone:
            pass  # a restart or a drop: the handshake ends here
    if state == DONE and not cell.log.since(mark, name):
        raise Violation("%s read done, but the robot received no %s after the trigger"
                        % (name, name))
    if state != DONE:
        raise StepFailed("%s ended in state %d: %s" % (name, state, text(plc, base + 3)))
    return state


def text(plc, address):
    raw = b"".join(struct.pack(">H", r) for r in plc.ir(address, 20))
    return raw.rstrip(b"\0").decode("utf-8", "replace")


def new_joint_target(cell, relative):
    rng = cell.rng
    if relative:
        return [round(rng.uniform(-6, 6), 3) for _ in range(6)]
    return [round(h + rng.uniform(-12, 12), 3) for h in HOME]


def move_done(cell, motion_before, target, relative_from, kind):
    """Done for a move: the motion count moved on from the value read
    before the trigger and the motion state reads 2; at that moment the
    robot (its own status) is at the target."""
    plc = cell.plc
    count = plc.wait_for(lambda: plc.ir(MOTION_COUNT)[0], lambda v: v != motion_before, 1,
                         "the motion count")
    if (count - motion_before) & 0xFFFF != 1:
        raise Violation("motion count moved from %d to %d for one move" % (motion_before, count))
    # The recipe's watchdog, as a PLC programmer sets one for a move: 5 s,
    # and on for as long as the arm is seen moving (a move slowed by a low
    # override takes as long as it takes; the gateway, too, ends no move
    # while the status shows the arm moving), up to a minute.
    end = time.monotonic() + 5

    def ended_or_overdue():
        now = time.monotonic()
        if plc.ir(MOTION_STATE)[0] != MOVING:
            return True
        if now > end and cell.watch.moving_at(now - 0.1):
            return False
        return now > end
    plc.wait(ended_or_overdue, 60, "the move to end")
    state = plc.ir(MOTION_STATE)[0]
    if state == MOVING:
        raise StepFailed("timeout: the move to end (motion state 1, the arm still, more than "
                         "5 s after the motion count moved)")
    if state != ARRIVED:
        raise StepFailed("move ended in motion state %d, the arm at %s, target %s%s" % (
            state, [round(j, 3) for j in cell.watch.joints()], target,
            " (relative)" if relative_from else ""))
    if kind == "joint":
        goal = [f32(t) + (relative_from[i] if relative_from else 0) for i, t in enumerate(target)]
        at = settled_joints(cell)
        if max(abs(a - g) for a, g in zip(at, goal)) > 0.5:
            raise Violation("motion state 2 with the arm at %s, target %s" % (at, goal))


def settled_joints(cell):
    """The joints as the robot sent them up to 100 ms after now: the watch's
    thread may run a document or two behind the gateway on a loaded
    machine, and an arm in position (or arrived) holds still."""
    read_at = time.monotonic()
    cell.plc.wait(lambda: cell.watch.docs and cell.watch.docs[-1][0] > read_at + 0.1, 2,
                  "the robot's status")
    return cell.watch.joints()


def joint_move(cell, relative):
    plc = cell.plc
    target = new_joint_target(cell, relative)
    speed = JOINT_SPEED
    cell.written_targets.append(("joint", relative, [f32(t) for t in target]))
    regs = f32_registers(target + [speed, 100.0]) + [1 if relative else 0]
    motion_before = plc.ir(MOTION_COUNT)[0]
    start = None
    if relative:
        # A relative move starts from where the arm is at the trigger: the
        # guide has the PLC start it in position.
        plc.wait(lambda: plc.di(INPOS), 2, "in position before a relative move")
        start = settled_joints(cell)
    command(cell, "joint_move", (JOINT_TARGET, regs))
    move_done(cell, motion_before, target, start, "joint")


def move_l(cell):
    """moveL: the whole block (HR 340-359, the unassigned 357 inside it) in
    one FC16, relative, a few mm."""
    plc = cell.plc
    rng = cell.rng
    offset = [round(rng.uniform(-10, 10), 3) for _ in range(3)] + [0.0, 0.0, 0.0]
    cell.written_targets.append(("cart", True, [f32(t) for t in offset]))
    regs = f32_registers(offset + [40.0, 500.0]) + [1, 0] + f32_registers([0.0])
    check(len(regs) == MOVEL_LAST - MOVEL_TARGET + 1, "the moveL block's length")
    motion_before = plc.ir(MOTION_COUNT)[0]
    command(cell, "moveL", (MOVEL_TARGET, regs))
    move_done(cell, motion_before, offset, None, "cart")


def mailbox_move(cell):
    """A joint move through the exactly-once mailbox: code, arguments and a
    new sequence number in one FC16; the mailbox count moves by one, ack and
    done echo the number."""
    plc = cell.plc
    target = new_joint_target(cell, False)
    cell.written_targets.append(("joint", False, [f32(t) for t in target]))
    seq = plc.ir(MAILBOX_ACK)[0] % 60000 + 1
    args = target + [JOINT_SPEED, 100.0, 0.0] + [0.0] * 3
    before = plc.ir(MAILBOX_COUNT)[0]
    motion_before = plc.ir(MOTION_COUNT)[0]
    mark = cell.mark()
    cell.plc_writes["joint_move"] += 1
    code = plc.write_regs(MAILBOX_CODE, [MAILBOX_JOINT_MOVE] + f32_registers(args) + [seq])
    now = plc.wait_for(lambda: plc.ir(MAILBOX_COUNT)[0], lambda v: v != before, 1,
                       "the mailbox count")
    if (now - before) & 0xFFFF != 1:
        raise Violation("mailbox count moved from %d to %d for one write" % (before, now))
    if code:
        raise StepFailed("mailbox refused with %02X: %s" % (code, text(plc, MAILBOX_STATE + 3)))
    plc.wait(lambda: plc.ir(MAILBOX_DONE)[0] == seq, 3, "done_seq")
    state = plc.ir(MAILBOX_STATE)[0]
    if state == DONE and not cell.log.since(mark, "joint_move"):
        raise Violation("mailbox done, but the robot received no joint_move")
    if state != DONE:
        raise StepFailed("mailbox state %d" % state)
    move_done(cell, motion_before, target, None, "joint")


def output(cell):
    """An output: write the coil, wait for its read-back input."""
    plc = cell.plc
    value = 1 - plc.di(OUTPUT_BACK)
    mark = cell.mark()
    cell.plc_writes["set_digital_output"] += 1
    code = plc.write_coil(OUTPUT, value)
    if code:
        raise StepFailed("output refused with %02X" % code)
    plc.wait(lambda: plc.di(OUTPUT_BACK) == value, 2, "the output's read-back")
    if not cell.log.since(mark, "set_digital_output"):
        raise Violation("the output read back, but the robot received no set_digital_output")


def program(cell):
    """Start a program: load it, play (wait for IR 102 = 3), run a little,
    stop (IR 102 = 0)."""
    plc = cell.plc
    name = "model/cell%d_%d.jks" % (cell.index, cell.rng.randrange(1 << 20))
    command(cell, "load_program", (PROGRAM_NAME, text_registers(name, 32)))
    command(cell, "play_program")
    plc.wait(lambda: plc.ir(INTERP_STATE)[0] == 3, 2, "the program running")
    end = time.monotonic() + cell.rng.uniform(0.05, 0.3)
    plc.wait(lambda: time.monotonic() > end, 1, "the program's run")
    command(cell, "stop_program")
    plc.wait(lambda: plc.ir(INTERP_STATE)[0] == 0 and plc.di(INPOS), 2, "the program stopped")


RECIPES = (("joint_move", lambda c: joint_move(c, False)),
           ("joint_move_relative", lambda c: joint_move(c, True)),
           ("moveL", move_l), ("mailbox_move", mailbox_move), ("output", output),
           ("program", program))


# ---- one run ----

def recover(cell):
    """After a fault: restore the signal, let the arm stop, check the bound,
    then the guide's recovery (start-up, fault reset)."""
    plc = cell.plc
    kind = cell.fault
    if cell.fault_time is None:
        return
    t0 = cell.fault_time
    was_moving = cell.watch.moving_at(t0)
    if was_moving:
        cell.events["%s while the arm moved" % kind] += 1
    if kind in STOPPING and was_moving:
        # The bound of a robot that stops at once; past it, only as long
        # as this one still brakes (up to its stopping time more).
        end = t0 + STOP_BOUND_S + 0.15
        last = t0 + cell.stop_bound_s + 0.15
        def waited():
            now = time.monotonic()
            return now > last or (now > end and
                                  cell.watch.stopped_since(t0, now) is not None)
        if plc.client is not None:  # a PLC still running scans meanwhile
            plc.wait(waited, cell.stop_bound_s + 1, "the bound")
        else:
            while not waited():
                time.sleep(PERIOD_MS / 1000)
        if cell.watch.moving_at(t0 + LIMIT_MS / 1000):
            cell.events["%s: the arm still moving at time_limit_ms" % kind] += 1
        stopped = cell.watch.stopped_since(t0, time.monotonic())
        if stopped is None:
            raise Violation("%s: the arm still moving %.2f s after the fault"
                            % (kind, time.monotonic() - t0))
        took = stopped - t0
        cell.figures[kind].append(took)
        if took > (LIMIT_MS + PERIOD_MS + REPLY_MS) / 1000:
            cell.events["%s: stopped later than time_limit_ms + period + reply" % kind] += 1
        # One escalation is the gateway's to make: a pause the arm does not
        # brake on (a program's next move starting as the fault came) is
        # followed by stop_program one status period and a reply after the
        # pause's reply (docs/plc-guide.md), and the arm brakes from then.
        bound = cell.stop_bound_s
        actions = [r for r in cell.log.since(getattr(cell, "fault_log_mark", 0))
                   if r.get("cmdName") in ("pause_program", "stop_program")]
        if len(actions) >= 2:
            cell.events["%s: escalated (%s)" % (kind, ", ".join(r["cmdName"] for r in actions[:2]))] += 1
            bound += ESCALATION_S
        if took > bound:
            raise Violation("%s: the arm stopped %.0f ms after the fault (bound %.0f ms, "
                            "braking %d ms, %d action(s) sent)"
                            % (kind, took * 1000, bound * 1000, cell.stop_ms, len(actions)))
    if kind in STOPPING and plc.client is not None and plc.ir(FAULT)[0] != 0:
        # The guide's reset, step 2: what the robot did about the fault.
        reaction = plc.wait_for(lambda: plc.ir(REACTION)[0], lambda v: v != 2, 1,
                                "the fault's reaction")
        cell.events["reaction %d" % reaction] += 1
        if reaction == 6:
            raise Violation("%s: reaction 6, the arm still moving after the stop" % kind)
    if kind == "estop":
        cell.press_estop(False)
    if kind == "plc_restart":
        time.sleep(cell.rng.uniform(0, 0.3))
        cell.plc.connect()
        if cell.rng.random() < 0.5:
            retained_triggers(cell)
    plc.beating = True
    if kind == "command_link":
        plc.wait(lambda: plc.di(ROWS[("discrete_input", "command_link_up")]), 5,
                 "the command link back")
        # The robot's own handler for the cut connection acts after its
        # limit: start-up (which stops a paused robot) comes after it.
        end = t0 + (ROBOT_LIMIT_MS + 3 * PERIOD_MS) / 1000
        plc.wait(lambda: time.monotonic() > end, 2, "the robot's own handler")


def one_run(cell, number):
    rng = cell.rng
    cell.fault = rng.choice(FAULTS)
    cell.fault_time = None
    cell.fault_at = cell.scans + rng.randrange(1, 80) if cell.fault != "none" else None
    cell.at_trigger = cell.fault in ("reconnect", "plc_restart") and rng.random() < 0.5
    steps = [rng.choice(RECIPES) for _ in range(rng.randint(1, 3))]
    cell.trace = ["run %d: %s, fault %s" % (number, [s[0] for s in steps], cell.fault)]
    cell.plc_late = False
    outcome = "done"
    try:
        for name, recipe in steps:
            cell.trace.append(name)
            recipe(cell)
    except (StepFailed, PlcRestart, PlcGone) as e:
        outcome = type(e).__name__ + ": " + str(e)
        cell.trace.append(outcome)
    if cell.fault_at is not None:  # the recipes ended first: the fault now, idle
        cell.fault_at = None
        try:
            cell.inject()
        except PlcRestart:
            pass
    if cell.fault == "none" and outcome != "done":
        # Two faults this shared machine makes by itself, both the gateway
        # right to react to: the PLC thread or the gateway's loop held up
        # longer than time_limit_ms (fault 1, fault 4).
        stalled = cell.plc.client is not None and cell.plc.ir(FAULT)[0] == 4
        if cell.plc_late:
            cell.events["the PLC's own scan late by time_limit_ms (fault 1)"] += 1
        elif stalled:
            cell.events["the gateway's loop stalled past time_limit_ms (fault 4)"] += 1
        else:
            raise Violation("no fault, and the recipe failed: %s" % outcome)
    recover(cell)
    for attempt in range(3):
        try:
            startup(cell)
            break
        except (PlcGone, StepFailed) as e:
            cell.trace.append("start-up again: %s" % e)
            try:
                cell.plc.connect()
            except PlcGone:
                time.sleep(0.2)
    else:
        raise Violation("the cell did not come back: %s" % cell.trace)
    check_robot_side(cell)
    return outcome


def check_robot_side(cell):
    """What the robot received: no target the PLC did not write, no move
    twice, no command more often than the PLC wrote it."""
    cell.log.poll()
    seen = collections.Counter()
    for name, req in cell.log.entries:
        if name == "joint_move":
            key = ("joint", bool(req.get("relFlag")), tuple(req["jointPosition"]))
        elif name == "moveL":
            key = ("cart", bool(req.get("relFlag")), tuple(req["cartPosition"]))
        else:
            if name in cell.plc_writes and name not in ("stop_program", "pause_program"):
                seen[name] += 1
            continue
        match = [t for t in cell.written_targets
                 if t[0] == key[0] and t[1] == key[1] and
                 all(abs(a - b) <= 1e-3 * max(1, abs(b)) for a, b in zip(key[2], t[2]))]
        if not match:
            raise Violation("the robot received %s to %s, a target the PLC never wrote"
                            % (name, list(key[2])))
        seen[("target",) + key] += 1
        if seen[("target",) + key] > 1:
            raise Violation("%s to %s reached the robot twice" % (name, list(key[2])))
    for name, n in seen.items():
        if isinstance(name, str) and n > cell.plc_writes[name]:
            raise Violation("the robot received %s %d times, the PLC wrote it %d times"
                            % (name, n, cell.plc_writes[name]))


def cell_loop(cell, runs, results, errors):
    try:
        cell.plc = Plc(cell)
        startup(cell)
        for number in range(runs):
            outcome = one_run(cell, number)
            results[cell.fault].append(outcome)
    except Exception as e:  # reported by the main thread
        cell.log.poll()
        robot = ["%s %s" % (n, json.dumps(r)[:120]) for n, r in cell.log.entries[-8:]]
        robot += [l for l in cell.gw.output().splitlines() if "motion:" in l][-3:]
        docs = cell.watch.snapshot(time.monotonic() - 3)
        now = time.monotonic()
        robot += ["%.2f s ago: %s estop %s" % (now - t, [round(j, 2) for j in joints], e)
                  for t, joints, e in docs[::max(1, len(docs) // 15)]]
        errors.append("cell %d: %s: %s\n    %s\n    the robot's last commands:\n      %s"
                      % (cell.index, type(e).__name__, e, "\n    ".join(cell.trace[-12:]),
                         "\n      ".join(robot)))


def test_plc_model_under_generated_faults():
    runs = int(os.environ.get("PLC_MODEL_RUNS") or "200")
    cells_n = int(os.environ.get("PLC_MODEL_CELLS", "6"))
    seed = int(os.environ.get("PLC_MODEL_SEED", str(random.randrange(1 << 30))))
    print("  seed %d (PLC_MODEL_SEED), %d runs in %d cells" % (seed, runs, cells_n), flush=True)
    figures = collections.defaultdict(list)
    events = collections.Counter()
    results = collections.defaultdict(list)
    errors = []
    cells = []
    started = time.monotonic()
    try:
        for i in range(cells_n):
            cells.append(Cell(i, random.Random(seed * 100 + i), figures, events))
        threads = [threading.Thread(target=cell_loop,
                                    args=(c, runs // cells_n + (c.index < runs % cells_n),
                                          results, errors))
                   for c in cells]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        for c in cells:
            c.close()
    took = time.monotonic() - started
    done = sum(len(v) for v in results.values())
    print("  %d runs in %.1f s; by fault: %s" % (
        done, took, ", ".join("%s %d" % (k, len(v)) for k, v in sorted(results.items()))))
    for kind, values in sorted(figures.items()):
        values.sort()
        print("  %s: the arm stopped %.0f ms (median) / %.0f ms (max) after the fault, %d moving"
              % (kind, 1000 * values[len(values) // 2], 1000 * values[-1], len(values)))
    for what, n in sorted(events.items()):
        print("  %s: %d" % (what, n))
    check(not errors, "seed %d:\n  %s" % (seed, "\n  ".join(errors)))
    check(done == runs, "%d of %d runs" % (done, runs))


# ---- faults at a chosen moment, one cell each, side by side ----

RAPID_RATE = hr("rapid_rate")
NOT_SENT, REFUSED, ROBOT_ERROR = 8, 7, 3
STOPPED = 3  # the motion state


def result_of(cell, name):
    base = ir("result_%s_state" % name)
    return cell.plc.ir(base)[0], text(cell.plc, base + 3)


def joint_registers(cell, target):
    cell.written_targets.append(("joint", False, [f32(t) for t in target]))
    return f32_registers(target + [JOINT_SPEED, 100.0]) + [0]


def arm_travel(cell, since):
    """The most any joint moved, in degrees, in the robot's own documents
    from 'since' on."""
    docs = cell.watch.snapshot(since)
    if not docs:
        return 0.0
    return max(abs(a - b) for d in docs for a, b in zip(d[1], docs[0][1]))


def case_fault_with_a_move_in_the_queue(cell):
    """A joint_move waits in the gateway's queue behind a setpoint the
    robot answers 600 ms late when motion enable drops: the PLC reads the
    move's own result 8, "not sent: a safety action took its place"; the
    robot receives no joint_move and the arm does not move; the guide's
    reset, then the same move triggered again, arrives."""
    plc = cell.plc
    name = "joint_move"
    count_at, trigger = ir("result_%s_count" % name), TRIGGERS[name]
    target = new_joint_target(cell, False)
    mark = cell.mark()
    plc.scan()
    check(plc.write_reg(RAPID_RATE, 1000) == 0, "rapid_rate refused")
    check(plc.write_regs(JOINT_TARGET, joint_registers(cell, target)) == 0,
          "joint_move's target refused")
    before = plc.ir(count_at)[0]
    cell.plc_writes[name] += 1
    check(plc.write_coil(trigger, 1) == 0, "joint_move's trigger refused")
    cell.fault, cell.fault_time = "motion_enable", time.monotonic()
    check(plc.write_coil(MOTION_ENABLE, 0) == 0, "motion enable 0 refused")
    state = plc.wait_for(lambda: plc.ir(ir("result_%s_state" % name))[0],
                         lambda v: v != PENDING, 3, "joint_move's result")
    plc.write_coil(trigger, 0)
    _, why = result_of(cell, name)
    count = plc.ir(count_at)[0]
    plc.wait(lambda: cell.log.since(mark, "rapid_rate"), 3, "the slow setpoint answered")
    try:  # jakasim logs what it reads as it reads it: the stop may be a line behind
        plc.wait(lambda: cell.log.since(mark, "stop_program"), 2, "stop_program at the robot")
    except StepFailed:
        pass  # reported below, with what the robot did receive
    travel = arm_travel(cell, cell.fault_time)
    received = [n for n, _ in cell.log.entries[mark:]]
    report = ("move in the queue at a fault: result %d '%s', count +%d; the robot received %s; "
              "the arm moved %.3f deg" % (state, why, (count - before) & 0xFFFF, received, travel))
    check(state == NOT_SENT and why == "not sent: a safety action took its place", report)
    check((count - before) & 0xFFFF == 1, report)
    check("joint_move" not in received and "stop_program" in received, report)
    check(travel < 0.01, report)
    recover(cell)
    startup(cell)
    motion_before = plc.ir(MOTION_COUNT)[0]
    command(cell, name, (JOINT_TARGET, joint_registers(cell, target)))
    move_done(cell, motion_before, target, None, "joint")
    check_robot_side(cell)
    return report + "; triggered again after the reset: arrived"


def case_full_queue(cell):
    """Setpoints the robot answers 300 ms late fill the gateway's queue: a
    joint_move trigger then is refused busy (06), its count moved by one
    and its own result 7 "busy: the command queue is full"; the PLC's
    stop_program is not refused, reads done, and reaches the robot ahead
    of the queued setpoints; no joint_move reaches the robot."""
    plc = cell.plc
    mark = cell.mark()
    codes = []
    for i in range(CMD_QUEUE_FILL):
        plc.scan()
        codes.append(plc.write_reg(RAPID_RATE, 300 + i))
        if codes[-1]:
            break
    check(codes[-1] == 6, "the queue never filled: %d setpoints accepted" % len(codes))
    target = new_joint_target(cell, False)
    try:
        command(cell, "joint_move", (JOINT_TARGET, joint_registers(cell, target)))
        raise Violation("joint_move accepted with the queue full")
    except StepFailed as e:
        check("refused with 06" in str(e), "joint_move with the queue full: %s" % e)
    move_state, move_why = result_of(cell, "joint_move")
    check(move_state == REFUSED and move_why == "busy: the command queue is full",
          "joint_move's own result %d '%s'" % (move_state, move_why))
    command(cell, "stop_program")
    received = [n for n, _ in cell.log.entries[mark:]]
    ahead = received.index("stop_program")
    report = ("full queue: %d setpoints accepted, then 06; joint_move 06, result %d '%s'; "
              "stop_program done, at the robot behind %d setpoints"
              % (len(codes) - 1, move_state, move_why, ahead))
    check(ahead <= 2, report)
    check("joint_move" not in received, report)
    check_robot_side(cell)
    return report


def case_refused_stop(cell):
    """The robot refuses the PLC's first stop_program (jakasim
    --fail-command stop_program --fail-times 1) while a joint_move runs:
    the stop's result reads 3, the motion state stays 1 while the arm goes
    on; the guide's second stop is accepted, and the motion state reads 3
    once the arm stands still, within the cell's stopping time."""
    plc = cell.plc
    target = [h + (50.0 if i == 0 else 0.0) for i, h in enumerate(HOME)]
    motion_before = plc.ir(MOTION_COUNT)[0]
    command(cell, "joint_move", (JOINT_TARGET, joint_registers(cell, target)))
    plc.wait(lambda: abs(cell.watch.joints()[0] - HOME[0]) > 3, 3, "the move under way")
    try:
        command(cell, "stop_program")
        raise Violation("the first stop_program read done: jakasim refuses it")
    except StepFailed as e:
        check("state %d" % ROBOT_ERROR in str(e), "the refused stop: %s" % e)
    at_refusal = cell.watch.joints()[0]
    plc.wait(lambda: abs(cell.watch.joints()[0] - at_refusal) > 2, 2,
             "the arm going on after the refused stop")
    state_after_refusal = plc.ir(MOTION_STATE)[0]
    check(state_after_refusal == MOVING, "motion state %d after a refused stop, the arm moving"
          % state_after_refusal)
    stop_at = time.monotonic()
    command(cell, "stop_program")
    state = plc.wait_for(lambda: plc.ir(MOTION_STATE)[0], lambda v: v != MOVING,
                         cell.stop_bound_s + 1, "the motion state to leave 1")
    stopped = cell.watch.stopped_since(stop_at, time.monotonic() + 0.1)
    joint = cell.watch.joints()[0]
    report = ("refused stop at joint 1 %.1f deg: motion state 1 while the arm went on; the "
              "second stop done, motion state %d with joint 1 at %.1f of %.0f deg, the arm "
              "still %.0f ms after it (braking %d ms)"
              % (at_refusal, state, joint, target[0],
                 1000 * ((stopped or time.monotonic()) - stop_at), cell.stop_ms))
    moved = (plc.ir(MOTION_COUNT)[0] - motion_before) & 0xFFFF
    check(state == STOPPED, report)
    check(moved == 1, "%s; the motion count moved by %d" % (report, moved))
    check(abs(joint - target[0]) > 1, "%s; the arm at the target" % report)
    check(stopped is not None and stopped - stop_at <= cell.stop_bound_s,
          "%s; bound %.0f ms" % (report, cell.stop_bound_s * 1000))
    check_robot_side(cell)
    return report


# More setpoints than the gateway's queue holds (CMD_QUEUE_CAPACITY 64).
CMD_QUEUE_FILL = 80
CASES = ((case_fault_with_a_move_in_the_queue, ("--reply-delay", "rapid_rate:600")),
         (case_full_queue, ("--reply-delay", "rapid_rate:300")),
         (case_refused_stop, ("--fail-command", "stop_program", "--fail-times", "1")))


def test_plc_model_faults_at_chosen_moments():
    """The three cases side by side, a cell each: a fault while a move
    waits in the gateway's queue, a full queue, a stop the robot refuses,
    each as the guide's recipes meet it."""
    seed = int(os.environ.get("PLC_MODEL_SEED", str(random.randrange(1 << 30))))
    reports, errors = {}, []

    def run_case(index, case, sim_args):
        cell = None
        try:
            cell = Cell(index, random.Random(seed * 100 + index), collections.defaultdict(list),
                        collections.Counter(), sim_args, CHOSEN_CONFIG)
            cell.plc = Plc(cell)
            startup(cell)
            reports[case.__name__] = case(cell)
        except Exception as e:  # reported below
            trace = " / ".join(cell.trace[-6:]) if cell else ""
            errors.append("%s: %s: %s %s" % (case.__name__, type(e).__name__, e, trace))
        finally:
            if cell:
                cell.close()
    threads = [threading.Thread(target=run_case, args=(i, case, args))
               for i, (case, args) in enumerate(CASES)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for name, report in sorted(reports.items()):
        print("  %s" % report, flush=True)
    check(not errors, "seed %d:\n  %s" % (seed, "\n  ".join(errors)))


TESTS = [test_plc_model_faults_at_chosen_moments, test_plc_model_under_generated_faults]

if __name__ == "__main__":
    run(TESTS)
