#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Commands as a PLC gives them: trigger coils, setpoint registers, the
exactly-once mailbox and the JSON mailbox, through pymodbus (and mbpoll
once) to the real jakagw and on to jakasim's command port.

Each test checks three things a PLC or the robot would notice: the exact
JSON the simulator received (jakasim --log-commands), the robot's state in
the status that follows, and the result registers. The error paths run end
to end: robot refusals, reply timeouts and late replies, the command link
going down, validation, repeated writes, busy mailboxes and write
permissions. A test that documents a gateway bug says so in its failure
line ("gateway bug: ...") and is left failing until the bug is fixed."""
import json
import socket
import struct
import subprocess
import time


from harness import (JAKASIM, Gateway, ModbusPlc, Process, Sim, TestFailure, check, log_lines, map_rows, mbap,
                     port_open, raw_client, recv_adu, run, running, wait_until)

# ---- the PLC interface: addresses a PLC program is written against ----

# Result blocks, 24 input registers each, in the command table's order.
RESULT_ORDER = ["power_on", "power_off", "enable_robot", "disable_robot", "clear_error",
                "shutdown", "load_program", "play_program", "pause_program",
                "resume_program", "stop_program", "rapid_rate", "set_digital_output",
                "set_analog_output", "set_tool_id", "set_user_id", "set_payload",
                "set_clsn_sensitivity", "joint_move", "end_move", "moveL"]
RESULT = {name: 4000 + 24 * k for k, name in enumerate(RESULT_ORDER)}
TRIGGER = {"power_on": 100, "power_off": 101, "enable_robot": 102, "disable_robot": 103,
           "clear_error": 104, "shutdown": 105, "load_program": 106, "play_program": 107,
           "pause_program": 108, "resume_program": 109, "stop_program": 110,
           "set_payload": 111, "joint_move": 112, "end_move": 113, "moveL": 114}
MAILBOX_CODE = {"power_on": 1, "power_off": 2, "enable_robot": 3, "disable_robot": 4,
                "clear_error": 5, "shutdown": 6, "load_program": 10, "play_program": 11,
                "pause_program": 12, "resume_program": 13, "stop_program": 14,
                "rapid_rate": 20, "set_digital_output": 21, "set_analog_output": 22,
                "set_tool_id": 23, "set_user_id": 24, "set_payload": 25,
                "set_clsn_sensitivity": 26, "joint_move": 30, "end_move": 31, "moveL": 32}
IDLE, PENDING, DONE, ROBOT_ERROR, TIMEOUT, LINK_DOWN, INVALID, REFUSED, NOT_SENT = range(9)
EX_NOT_PERMITTED, EX_INVALID, EX_BUSY, EX_LINK_DOWN = 0x01, 0x03, 0x06, 0x0B

# Coils.
C_JSON_TRIGGER, C_CABINET_DO, C_TOOL_DO, C_EXTIO_DO = 120, 200, 216, 224
# Holding registers.
H_HEARTBEAT, H_RAPID_RATE, H_TOOL_ID, H_USER_ID, H_COLLISION = 0, 100, 101, 102, 103
H_CABINET_AO, H_EXTIO_AO, H_PAYLOAD_MASS, H_PAYLOAD_CENTROID = 110, 126, 150, 152
H_PROGRAM_NAME, PROGRAM_NAME_REGS = 200, 32
H_JOINT_MOVE, H_END_MOVE, H_MOVEL = 300, 320, 340
H_MAILBOX, H_MAILBOX_SEQ = 400, 425
H_JSON_REQUEST, JSON_REQUEST_REGS = 500, 120
# Discrete inputs.
D_COMMAND_LINK_UP, D_STATUS_FRESH = 1, 2
D_ENABLED, D_PAUSED, D_INPOS, D_POWERED_ON = 17, 18, 19, 22
D_TIO_DOUT, D_EXTIO_DO, D_DOUT = 72, 192, 512
# Input registers.
I_MAGIC, I_COMMAND_RECONNECTS, I_ROBOT_HANDLE = 0, 34, 64
I_TASK_STATE, I_INTERP_STATE, I_TOOL_ID, I_USER_ID = 100, 102, 104, 105
I_ERRCODE, I_RAPIDRATE, I_RAPIDRATE_PERMILLE = 110, 112, 114
I_JOINTS, I_TCP, I_EXTIO_AO, I_AOUT = 200, 212, 1164, 1556
I_MAILBOX_ACK, I_MAILBOX_DONE, I_MAILBOX_STATE, I_MAILBOX_CODE, I_MAILBOX_MSG = (
    4600, 4601, 4602, 4603, 4605)
I_JSON_STATE, I_JSON_CODE, I_JSON_MSG, I_JSON_TRUNCATED, I_JSON_LENGTH, I_JSON_REPLY = (
    4650, 4651, 4653, 4673, 4674, 4700)
JSON_REPLY_REGS = 256
I_LOADED_PROGRAM, I_PROGRAM_STATE, I_VERSION = 5002, 5034, 5035
I_PAYLOAD_MASS, I_PAYLOAD_CENTROID, I_COLLISION_LEVEL = 5052, 5054, 5060
HANDLE_ACCEPTED = 2
PROGRAM_IDLE, PROGRAM_RUNNING, PROGRAM_PAUSED = 0, 1, 2

# This suite is about what each command sends and answers; the cases that
# start programs or move do so with no PLC heartbeat, which
# [network_exception] require_heartbeat refuses by default (its own cases
# are test_contract.py's).
NO_HEARTBEAT = "[network_exception]\nrequire_heartbeat = false\n"
MOTION_ON = "[commands]\nmotion = true\n" + NO_HEARTBEAT
HOME = [0.0, 90.0, 90.0, 0.0, 90.0, 0.0]


class GatewayBug(TestFailure):
    pass


def gateway_bug(description):
    """Marks a test that shows a gateway bug: its failure line says which."""
    def wrap(test):
        def run_test():
            try:
                test()
            except TestFailure as e:
                raise GatewayBug("%s -- %s" % (description, e)) from None
        run_test.__name__ = test.__name__
        return run_test
    return wrap


# ---- encoding ----

def f32_regs(values):
    return list(struct.unpack(">%dH" % (2 * len(values)),
                              struct.pack(">%df" % len(values), *values)))


def f32_of(v):
    return struct.unpack(">f", struct.pack(">f", v))[0]


def text_regs(data, regs):
    if isinstance(data, str):
        data = data.encode()
    check(len(data) <= 2 * regs, "text longer than %d registers" % regs)
    return list(struct.unpack(">%dH" % regs, data.ljust(2 * regs, b"\0")))


def regs_text(regs):
    return b"".join(struct.pack(">H", r) for r in regs).rstrip(b"\0").decode("utf-8")


def cjson_number(v):
    """A number as the gateway's cJSON prints it."""
    if v == int(v) and abs(v) < 2 ** 31:
        return "%d" % v
    text = "%1.15g" % v
    return text if float(text) == v else "%1.17g" % v


def sent_float(v):
    """A value from an f32 register as the gateway sends it (7 digits)."""
    return cjson_number(float("%.7g" % f32_of(v)))


def numbers(values):
    return "[" + ",".join(sent_float(v) for v in values) + "]"


# ---- the simulator's command log ----

LOG_MARK = "jakasim: command "


def robot_commands(sim):
    """(request text, cmdName, reply text) of every command jakasim got."""
    out = []
    decoder = json.JSONDecoder()
    for line in sim.output().splitlines():
        at = line.find(LOG_MARK)
        if at < 0:
            continue
        rest = line[at + len(LOG_MARK):]
        if not rest.startswith("{"):
            continue  # "command client connected"
        try:
            request, end = decoder.raw_decode(rest)
        except ValueError:
            out.append((rest, None, None))
            continue
        name = request.get("cmdName") if isinstance(request, dict) else None
        reply = rest[end:]
        out.append((rest[:end], name, reply[4:] if reply.startswith(" -> ") else None))
    return out


def sent(sim, name):
    """The request texts jakasim received with cmdName 'name', in order."""
    return [c[0] for c in robot_commands(sim) if c[1] == name]


def replies(sim, name):
    return [c[2] for c in robot_commands(sim) if c[1] == name]


def housekeeping(name):
    """What the gateway sends by itself on connecting and after commands."""
    return name is not None and (name.startswith("get_")
                                 or name == "set_network_exception_handle")


# ---- a PLC ----

class Plc(ModbusPlc):
    """A Modbus master as a PLC uses it (harness.ModbusPlc), with the
    command rows by name. Writes return 0 or the exception code; pymodbus
    never retries, so nothing is sent twice behind our back."""

    def __init__(self, gw, source=None):
        super().__init__(gw.modbus_port, source)
        self.gw = gw

    def trigger(self, name):
        """A trigger coil as a PLC pulses it: 0, then 1 (0 -> 1 sends)."""
        check(self.coil(TRIGGER[name], 0) == 0, "re-arming %s" % name)
        return self.coil(TRIGGER[name], 1)

    def i32(self, address):
        v = self.u32(address)
        return v - (1 << 32) if v & 0x80000000 else v

    def f32(self, address, count=1):
        regs = self.ir(address, 2 * count)
        return list(struct.unpack(">%df" % count, struct.pack(">%dH" % (2 * count), *regs)))

    def text(self, address, regs):
        return regs_text(self.ir(address, regs))

    def result(self, name):
        base = RESULT[name]
        regs = self.ir(base, 23)
        code = regs[1] << 16 | regs[2]
        code = code - (1 << 32) if code & 0x80000000 else code
        return regs[0], code, regs_text(regs[3:23])

    def wait_result(self, name, timeout=10):
        """The result once the robot answered (or the gateway gave up). A
        write's answer comes after its command was queued, so 'pending'
        is already showing when this starts."""
        wait_until(lambda: self.ir(RESULT[name])[0] != PENDING, timeout, "%s's result" % name)
        return self.result(name)

    def expect_done(self, name, timeout=10):
        state, code, msg = self.wait_result(name, timeout)
        check((state, code) == (DONE, 0), "%s: result state %d, code %d, message %r"
              % (name, state, code, msg))

    def wait_di(self, address, value, timeout=10, what=None):
        wait_until(lambda: self.di(address)[0] == value, timeout,
                   what or "discrete input %d = %d" % (address, value))

    def wait_ir(self, address, value, timeout=10, what=None):
        wait_until(lambda: self.ir(address)[0] == value, timeout,
                   what or "input register %d = %d" % (address, value))

    def ready(self, timeout=15):
        """The command link is up and the robot accepted the gateway's
        network-exception handler: commands are accepted from here on."""
        self.wait_di(D_COMMAND_LINK_UP, 1, timeout, "the command link")
        self.wait_di(D_STATUS_FRESH, 1, timeout, "fresh status")
        self.wait_ir(I_ROBOT_HANDLE, HANDLE_ACCEPTED, timeout,
                     "the robot to accept its network-exception handler")

    def mailbox(self, seq, code, args=()):
        """Code, arguments and sequence number in one write, as the PLC guide
        asks."""
        values = list(args) + [0.0] * (12 - len(args))
        return self.regs(H_MAILBOX, [code] + f32_regs(values) + [seq])

    def wait_mailbox_done(self, seq, timeout=10):
        wait_until(lambda: self.ir(I_MAILBOX_DONE)[0] == seq, timeout,
                   "mailbox done_seq %d" % seq)
        regs = self.ir(I_MAILBOX_STATE, 23)
        code = regs[1] << 16 | regs[2]
        return regs[0], code - (1 << 32) if code & 0x80000000 else code, regs_text(regs[3:23])

    def json_request(self, text):
        """Writes the JSON mailbox's request in one FC16 and pulses its
        trigger; returns the trigger write's outcome."""
        check(self.regs(H_JSON_REQUEST, text_regs(text, JSON_REQUEST_REGS)) == 0,
              "write the JSON request")
        check(self.coil(C_JSON_TRIGGER, 0) == 0, "re-arm the JSON trigger")
        return self.coil(C_JSON_TRIGGER, 1)

    def json_result(self, timeout=10):
        wait_until(lambda: self.ir(I_JSON_STATE)[0] != PENDING, timeout, "the JSON reply")
        regs = self.ir(I_JSON_STATE, 23)
        code = regs[1] << 16 | regs[2]
        code = code - (1 << 32) if code & 0x80000000 else code
        return {"state": regs[0], "code": code, "msg": regs_text(regs[3:23]),
                "truncated": self.ir(I_JSON_TRUNCATED)[0], "length": self.u32(I_JSON_LENGTH),
                "reply": regs_text(self.ir(I_JSON_REPLY, JSON_REPLY_REGS))}

    def program_name(self, name):
        return self.regs(H_PROGRAM_NAME, text_regs(name, PROGRAM_NAME_REGS))


def fence(plc, sim, tool_id=0):
    """A harmless command (select tool frame 'tool_id'), waited for in the
    robot's log: whatever the gateway had sent before it is logged by now,
    since one connection carries both, in order."""
    before = len(sent(sim, "set_tool_id"))
    check(plc.reg(H_TOOL_ID, tool_id) == 0, "fence write")
    wait_until(lambda: len(sent(sim, "set_tool_id")) > before, 10, "the fence command")


def power_and_enable(plc):
    for name in ("power_on", "enable_robot"):
        check(plc.trigger(name) == 0, "%s refused" % name)
        plc.expect_done(name)
    plc.wait_di(D_ENABLED, 1, 5, "enabled in the status")


def close_to(a, b, tol):
    return all(abs(x - y) <= tol for x, y in zip(a, b))


class SimOn(Sim):
    """jakasim on given ports: the same robot address after a restart."""

    def __init__(self, status_port, command_port, *args):
        self.status_port, self.command_port = status_port, command_port
        Process.__init__(self, "jakasim", [JAKASIM, "--status-port", str(status_port),
                                           "--command-port", str(command_port)] + list(args))
        wait_until(lambda: port_open(status_port) and port_open(command_port), 30,
                   "jakasim to listen again")


# ---- the interface itself ----

def test_addresses_match_the_register_map():
    """The addresses these tests (and PLC programs) use are the map's."""
    rows = map_rows()

    def has(source, table, address):
        return any(r["source"] == source and r["table"] == table and
                   int(r["address"]) == address for r in rows)

    for name, base in RESULT.items():
        for member, offset in (("state", 0), ("error_code", 1), ("error_msg", 3)):
            check(has("gw:result.%s.%s" % (name, member), "input_register", base + offset),
                  "result %s.%s is not input register %d" % (name, member, base + offset))
    for name, address in TRIGGER.items():
        check(has("cmd:" + name, "coil", address), "trigger %s is not coil %d" % (name, address))
    for source, table, address in (
            ("gw:mailbox.code", "holding_register", H_MAILBOX),
            ("gw:mailbox.seq", "holding_register", H_MAILBOX_SEQ),
            ("gw:json.request", "holding_register", H_JSON_REQUEST),
            ("gw:json.trigger", "coil", C_JSON_TRIGGER),
            ("gw:mailbox.ack_seq", "input_register", I_MAILBOX_ACK),
            ("gw:mailbox.done_seq", "input_register", I_MAILBOX_DONE),
            ("gw:mailbox.state", "input_register", I_MAILBOX_STATE),
            ("gw:mailbox.error_code", "input_register", I_MAILBOX_CODE),
            ("gw:json.state", "input_register", I_JSON_STATE),
            ("gw:json.error_code", "input_register", I_JSON_CODE),
            ("gw:json.reply_truncated", "input_register", I_JSON_TRUNCATED),
            ("gw:json.reply_length", "input_register", I_JSON_LENGTH),
            ("gw:json.reply", "input_register", I_JSON_REPLY),
            ("gw:info.loaded_program", "input_register", I_LOADED_PROGRAM),
            ("gw:info.program_state", "input_register", I_PROGRAM_STATE),
            ("gw:info.collision_level", "input_register", I_COLLISION_LEVEL),
            ("gw:info.payload_mass", "input_register", I_PAYLOAD_MASS),
            ("cmd:load_program.programName", "holding_register", H_PROGRAM_NAME),
            ("cmd:rapid_rate.rate_value", "holding_register", H_RAPID_RATE),
            ("cmd:set_tool_id.tool_id", "holding_register", H_TOOL_ID),
            ("cmd:set_clsn_sensitivity.sensitivityVal", "holding_register", H_COLLISION),
            ("cmd:set_payload.mass", "holding_register", H_PAYLOAD_MASS),
            ("cmd:joint_move.jointPosition[0]", "holding_register", H_JOINT_MOVE),
            ("cmd:end_move.endPosition[0]", "holding_register", H_END_MOVE),
            ("cmd:moveL.cartPosition[0]", "holding_register", H_MOVEL),
            ("powered_on", "discrete_input", D_POWERED_ON),
            ("enabled", "discrete_input", D_ENABLED),
            ("paused", "discrete_input", D_PAUSED),
            ("dout[0]", "discrete_input", D_DOUT),
            ("extio.status[1][0]", "discrete_input", D_EXTIO_DO),
            ("tio_dout[0]", "discrete_input", D_TIO_DOUT),
            ("aout[0]", "input_register", I_AOUT),
            ("extio.status[3][0]", "input_register", I_EXTIO_AO),
            ("rapidrate", "input_register", I_RAPIDRATE)):
        check(has(source, table, address), "%s is not %s %d" % (source, table, address))
    dos = [r for r in rows if r["source"] == "cmd:set_digital_output.value"]
    check([int(r["address"]) for r in dos] == list(range(200, 216)) + [216, 217]
          + list(range(224, 240)), "digital output coils %s" % [r["address"] for r in dos])


# ---- every mapped command, one by one ----

def test_power_enable_disable_clear_error_by_trigger_coils():
    with running(["--log-commands", "--test-pattern"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.u32(I_ERRCODE) == 0x2B0C0001, "the test pattern's error code is showing")
        figures = []
        for name, bit, value, task_state in (("power_on", D_POWERED_ON, 1, 2),
                                             ("enable_robot", D_ENABLED, 1, 4),
                                             ("disable_robot", D_ENABLED, 0, 2),
                                             ("power_off", D_POWERED_ON, 0, 1)):
            t = time.monotonic()
            check(plc.trigger(name) == 0, "%s refused" % name)
            plc.expect_done(name)
            done = time.monotonic() - t
            plc.wait_di(bit, value, 5, "%s in the status" % name)
            plc.wait_ir(I_TASK_STATE, task_state, 5, "task_state %d after %s" % (task_state, name))
            figures.append("%s %.0f/%.0f ms" % (name, done * 1000, (time.monotonic() - t) * 1000))
            check(sent(sim, name) == ['{"cmdName":"%s"}' % name], "%s sent as %s"
                  % (name, sent(sim, name)))
        check(plc.trigger("clear_error") == 0, "clear_error refused")
        plc.expect_done("clear_error")
        check(sent(sim, "clear_error") == ['{"cmdName":"clear_error"}'], "clear_error JSON")
        wait_until(lambda: plc.u32(I_ERRCODE) == 0, 5, "errcode 0 after clear_error")
        # A trigger written 1 again, alone or by FC15, sends nothing; 0
        # re-arms it and the next 1 sends once more.
        check(plc.coil(TRIGGER["clear_error"], 1) == 0, "second 1")
        check(plc.coils(TRIGGER["clear_error"], [1]) == 0, "FC15 1")
        fence(plc, sim)
        check(len(sent(sim, "clear_error")) == 1, "a trigger written 1 twice sent %d times"
              % len(sent(sim, "clear_error")))
        check(plc.coil(TRIGGER["clear_error"], 0) == 0, "re-arm")
        fence(plc, sim, 1)
        check(len(sent(sim, "clear_error")) == 1, "writing 0 sent a command")
        check(plc.coil(TRIGGER["clear_error"], 1) == 0, "1 after re-arming")
        plc.expect_done("clear_error")
        check(len(sent(sim, "clear_error")) == 2, "re-armed trigger did not send again")
        print("  write to done / to status: " + ", ".join(figures))
        plc.close()


def test_robot_refusal_surfaces_its_code_and_message():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.trigger("enable_robot") == 0, "the write is accepted; the robot refuses")
        state, code, msg = plc.wait_result("enable_robot")
        check(sent(sim, "enable_robot") == ['{"cmdName":"enable_robot"}'], "enable JSON")
        robot = json.loads(replies(sim, "enable_robot")[0])
        check((state, code, msg) == (ROBOT_ERROR, 2, robot["errorMsg"]) and
              msg == "robot is powered off",
              "result (%d, %d, %r), robot replied %r" % (state, code, msg, robot))
        check(plc.di(D_ENABLED)[0] == 0, "enabled despite the refusal")
        print("  enable while powered off: state %d, errorCode %d, %r" % (state, code, msg))
        plc.close()


def test_a_robot_message_cannot_forge_a_log_line():
    """The robot's errorMsg holds a newline, a forged "<3>jakagw:" entry,
    a CR and an escape sequence: the PLC reads it as it came, and the
    gateway's log gets exactly one line for it (journald splits stderr at
    newlines, so one line is one journal entry), with the bytes escaped
    and the Chinese text kept."""
    message = "报警\n<3>jakagw: forged\r\x1b[2K"
    with running(["--fail-command", "power_on", "--fail-message", message]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.trigger("power_on") == 0, "power_on write")
        state, code, msg = plc.wait_result("power_on")
        check((state, code, msg) == (ROBOT_ERROR, 2, message),
              "result (%d, %d, %r)" % (state, code, msg))
        plc.close()
        wait_until(lambda: log_lines(gw, "command power_on"), 5, "the log line")
        out = gw.output()
    # The audit trail's record of it is one escaped line too.
    audit = [l for l in out.splitlines() if "forged" in l and l.startswith("<5>audit: ")]
    check(len(audit) == 1 and audit[0].endswith("报警\\x0a<3>jakagw: forged\\x0d\\x1b[2K"),
          "audit line: %r" % audit)
    lines = [l for l in out.splitlines() if "forged" in l and not l.startswith("<5>audit: ")]
    check(len(lines) == 1 and lines[0].startswith("<5>command power_on: robot error (2) "),
          "forged text on %d lines: %r" % (len(lines), lines))
    check(lines[0].endswith("报警\\x0a<3>jakagw: forged\\x0d\\x1b[2K"),
          "not escaped as expected: %r" % lines[0])
    check("\x1b" not in out and "\r" not in out, "a control byte reached the log")


def test_program_recipe_as_a_plc_runs_it():
    """Power on, enable, load, play, pause, resume, stop: each step written,
    then awaited on its result register and on the status."""
    with running(["--log-commands"], NO_HEARTBEAT) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        t0 = time.monotonic()
        steps = []

        def step(name, waits):
            t = time.monotonic()
            check(plc.trigger(name) == 0, "%s refused" % name)
            plc.expect_done(name)
            for what, cond in waits:
                wait_until(cond, 5, "%s: %s" % (name, what))
            steps.append("%s %.0f" % (name, (time.monotonic() - t) * 1000))

        step("power_on", [("powered_on", lambda: plc.di(D_POWERED_ON)[0] == 1)])
        step("enable_robot", [("enabled", lambda: plc.di(D_ENABLED)[0] == 1)])
        check(plc.program_name("track/recipe.jks") == 0, "program name write")
        check(plc.hr(H_PROGRAM_NAME, 8) == text_regs("track/recipe.jks", 8), "name reads back")
        step("load_program", [("loaded program name",
                               lambda: plc.text(I_LOADED_PROGRAM, 32) == "track/recipe.jks")])
        step("play_program", [("interp_state running", lambda: plc.ir(I_INTERP_STATE)[0] == 3),
                              ("program state running",
                               lambda: plc.ir(I_PROGRAM_STATE)[0] == PROGRAM_RUNNING)])
        before = plc.f32(I_JOINTS, 6)
        wait_until(lambda: plc.f32(I_JOINTS, 6) != before, 3, "the program to move the arm")
        step("pause_program", [("paused bit", lambda: plc.di(D_PAUSED)[0] == 1),
                               ("program state paused",
                                lambda: plc.ir(I_PROGRAM_STATE)[0] == PROGRAM_PAUSED)])
        step("resume_program", [("paused bit cleared", lambda: plc.di(D_PAUSED)[0] == 0),
                                ("program state running",
                                 lambda: plc.ir(I_PROGRAM_STATE)[0] == PROGRAM_RUNNING)])
        step("stop_program", [("interp_state idle", lambda: plc.ir(I_INTERP_STATE)[0] == 0),
                              ("program state idle",
                               lambda: plc.ir(I_PROGRAM_STATE)[0] == PROGRAM_IDLE)])
        check(sent(sim, "load_program") ==
              ['{"cmdName":"load_program","programName":"track/recipe.jks"}'],
              "load_program JSON %s" % sent(sim, "load_program"))
        for name in ("play_program", "pause_program", "resume_program", "stop_program"):
            check(sent(sim, name) == ['{"cmdName":"%s"}' % name], "%s JSON %s"
                  % (name, sent(sim, name)))
        print("  recipe in %.2f s; ms per step: %s" % (time.monotonic() - t0, ", ".join(steps)))
        plc.close()


def test_setpoints_rapid_rate_tool_frame_collision_level():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.reg(H_RAPID_RATE, 250) == 0, "rapid rate write")
        plc.expect_done("rapid_rate")
        check(sent(sim, "rapid_rate") == ['{"cmdName":"rapid_rate","rate_value":0.25}'],
              "rapid_rate JSON %s" % sent(sim, "rapid_rate"))
        plc.wait_ir(I_RAPIDRATE_PERMILLE, 250, 5, "rapidrate 250 per mille in the status")
        check(plc.f32(I_RAPIDRATE)[0] == 0.25, "rapidrate float")
        check(plc.reg(H_TOOL_ID, 4) == 0, "tool id write")
        plc.expect_done("set_tool_id")
        plc.wait_ir(I_TOOL_ID, 4, 5, "current_tool_id 4")
        check(plc.reg(H_TOOL_ID, 4) == 0, "tool id again")
        plc.expect_done("set_tool_id")
        check(sent(sim, "set_tool_id") == ['{"cmdName":"set_tool_id","tool_id":4}'] * 2,
              "a setpoint sends on every write: %s" % sent(sim, "set_tool_id"))
        check(plc.reg(H_COLLISION, 2) == 0, "collision level write")
        plc.expect_done("set_clsn_sensitivity")
        check(sent(sim, "set_clsn_sensitivity") ==
              ['{"cmdName":"set_clsn_sensitivity","sensitivityVal":2}'],
              "set_clsn_sensitivity JSON %s" % sent(sim, "set_clsn_sensitivity"))
        plc.wait_ir(I_COLLISION_LEVEL, 2, 5, "collision level 2 fetched back")
        check(plc.reg(H_COLLISION, 6) == EX_INVALID, "collision level 6 accepted")
        check(plc.reg(H_TOOL_ID, 11) == EX_INVALID, "tool id 11 accepted")
        fence(plc, sim, 4)
        check(len(sent(sim, "set_clsn_sensitivity")) == 1, "a refused value was sent")
        plc.close()


def test_set_user_id_selects_the_user_frame():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.reg(H_USER_ID, 5) == 0, "user id write")
        result = plc.wait_result("set_user_id")
        check(sent(sim, "set_user_id") == ['{"cmdName":"set_user_id","user_frame_id":5}'],
              "set_user_id JSON %s (manual 4.33: user_frame_id); result %s"
              % (sent(sim, "set_user_id"), result))
        check(result[:2] == (DONE, 0), "result %s" % (result,))
        plc.wait_ir(I_USER_ID, 5, 5, "current_user_id 5")
        check(plc.mailbox(1, MAILBOX_CODE["set_user_id"], [7]) == 0, "mailbox write")
        plc.wait_mailbox_done(1)
        check(sent(sim, "set_user_id")[-1] == '{"cmdName":"set_user_id","user_frame_id":7}',
              "mailbox set_user_id JSON %s" % sent(sim, "set_user_id")[-1])
        plc.close()


def test_digital_outputs_cabinet_tool_and_extension():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        groups = [("cabinet", C_CABINET_DO, 16, 0, 1, D_DOUT + 1),
                  ("tool", C_TOOL_DO, 2, 1, 0, D_TIO_DOUT),
                  ("extension", C_EXTIO_DO, 16, 2, 0, D_EXTIO_DO)]
        expected = []
        t = time.monotonic()
        for label, coil, n, io_type, first, _ in groups:
            for k in range(n):
                check(plc.coil(coil + k, 1) == 0, "%s DO %d write" % (label, k))
                expected.append('{"cmdName":"set_digital_output","type":%d,"index":%d,"value":1}'
                                % (io_type, first + k))
        plc.expect_done("set_digital_output")
        for label, coil, n, io_type, first, bit in groups:
            wait_until(lambda: plc.di(bit, n) == [1] * n, 5, "%s outputs on in the status" % label)
        # FC15: one write per group sets them all back to 0, one command each.
        for label, coil, n, io_type, first, _ in groups:
            check(plc.coils(coil, [0] * n) == 0, "%s FC15" % label)
            expected += ['{"cmdName":"set_digital_output","type":%d,"index":%d,"value":0}'
                         % (io_type, first + k) for k in range(n)]
        wait_until(lambda: len(sent(sim, "set_digital_output")) == len(expected), 10,
                   "%d set_digital_output commands" % len(expected))
        for label, coil, n, io_type, first, bit in groups:
            wait_until(lambda: plc.di(bit, n) == [0] * n, 5, "%s outputs off in the status" % label)
        got = sent(sim, "set_digital_output")
        check(got == expected, "set_digital_output sequence differs at %s"
              % next(((i, a, b) for i, (a, b) in enumerate(zip(got, expected)) if a != b), None))
        errors = [r for r in replies(sim, "set_digital_output") if '"errorCode": "0"' not in r]
        check(not errors, "the robot refused: %s" % errors[:2])
        check(plc.di(D_DOUT, 1) == [0], "cabinet DO index 0 touched (coil 200 is DO 1)")
        print("  %d digital outputs set and cleared in %.2f s"
              % (len(expected), time.monotonic() - t))
        plc.close()


def test_setpoint_result_waits_for_the_last_of_a_multiple_write():
    with running(["--log-commands", "--reply-delay-ms", "150",
                  "--delay-command", "set_digital_output"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.coils(C_CABINET_DO, [1] * 8) == 0, "FC15 of 8 outputs")
        plc.wait_result("set_digital_output")
        outputs = plc.di(D_DOUT + 1, 8)

        def answered():
            return sum("delayed reply to set_digital_output sent" in line
                       for line in sim.output().splitlines())

        # The robot answers every 150 ms: its log may trail the reply by
        # moments, never by the 0.9 s six more replies take.
        try:
            wait_until(lambda: answered() == 8, 0.1, "the log")
        except TestFailure:
            pass
        answered = answered()
        wait_until(lambda: plc.di(D_DOUT + 1, 8) == [1] * 8, 10, "all 8 outputs on")
        check(answered == 8, "result 'done' after %d of 8 replies; outputs then %s"
              % (answered, outputs))
        plc.close()


def test_analog_outputs_cabinet_and_extension():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        cabinet = [0.5 + 1.25 * i for i in range(6)] + [3.3]  # AO 1-7 (4.27)
        extension = [-2.5 + i for i in range(8)]
        check(plc.regs(H_CABINET_AO, f32_regs(cabinet)) == 0, "cabinet AO FC16")
        check(plc.regs(H_EXTIO_AO, f32_regs(extension)) == 0, "extension AO FC16")
        expected = ['{"cmdName":"set_analog_output","type":0,"index":%d,"value":%s}'
                    % (i + 1, sent_float(v)) for i, v in enumerate(cabinet)]
        expected += ['{"cmdName":"set_analog_output","type":2,"index":%d,"value":%s}'
                     % (i, sent_float(v)) for i, v in enumerate(extension)]
        wait_until(lambda: len(sent(sim, "set_analog_output")) == 15, 10, "15 AO commands")
        got = sent(sim, "set_analog_output")
        check(got == expected, "set_analog_output JSON %s" % got)
        check('"value":3.3}' in got[6], "3.3 (f32 3.2999999523) not sent as 3.3: %s" % got[6])
        wait_until(lambda: close_to(plc.f32(I_AOUT + 2, 7), cabinet, 1e-6), 5,
                   "cabinet AO 1-7 in the status (aout[1..7])")
        wait_until(lambda: close_to(plc.f32(I_EXTIO_AO, 8), extension, 1e-6), 5,
                   "extension AO in the status")
        state, code, msg = plc.wait_result("set_analog_output")
        check((state, code) == (DONE, 0), "result %d %d %r" % (state, code, msg))
        plc.close()


def test_set_payload_with_its_parameters():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.regs(H_PAYLOAD_MASS, f32_regs([2.5])) == 0, "mass")
        check(plc.regs(H_PAYLOAD_CENTROID, f32_regs([10, -20, 30.5])) == 0, "centroid")
        check(plc.trigger("set_payload") == 0, "set_payload trigger")
        plc.expect_done("set_payload")
        check(sent(sim, "set_payload") ==
              ['{"cmdName":"set_payload","mass":2.5,"centroid":[10,-20,30.5]}'],
              "set_payload JSON %s" % sent(sim, "set_payload"))
        wait_until(lambda: plc.f32(I_PAYLOAD_MASS) == [2.5] and
                   plc.f32(I_PAYLOAD_CENTROID, 3) == [10, -20, 30.5], 5,
                   "the payload fetched back (get_payload)")
        plc.close()


def test_shutdown_and_motion_refused_by_default():
    """Without [commands] allow_shutdown and motion: exception 01 from every
    way in, the reason in the result registers, and nothing sent."""
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        for name in ("shutdown", "joint_move", "end_move", "moveL"):
            check(plc.trigger(name) == EX_NOT_PERMITTED, "%s trigger not refused with 01" % name)
            state, _, msg = plc.result(name)
            check(state == REFUSED and msg.startswith(("shutdown off", "motion off")),
                  "%s result %d %r" % (name, state, msg))
            check(plc.read_coils(TRIGGER[name])[0] == 0, "%s coil kept the refused 1" % name)
        for seq, name in enumerate(("shutdown", "joint_move", "end_move", "moveL"), 1):
            check(plc.mailbox(seq, MAILBOX_CODE[name]) == EX_NOT_PERMITTED,
                  "mailbox %s not refused" % name)
            check(plc.ir(I_MAILBOX_ACK)[0] == 0, "a refused mailbox command acknowledged")
        for text in ('{"cmdName":"shutdown"}',
                     '{"cmdName":"joint_move","relFlag":0,"jointPosition":[0,90,90,0,90,0],'
                     '"speed":20,"accel":20}',
                     '{"cmdName":"jog","jog_mode":1,"coord_map":1,"jnum":1,"jogvel":30}',
                     '{"cmdName":"servo_move","relFlag":1}'):
            check(plc.json_request(text) == EX_NOT_PERMITTED, "JSON %s not refused" % text)
            check(plc.ir(I_JSON_STATE)[0] == REFUSED, "JSON state after refusing %s" % text)
        fence(plc, sim)
        names = {c[1] for c in robot_commands(sim)}
        check(not names & {"shutdown", "joint_move", "end_move", "moveL", "jog", "servo_move"},
              "refused commands reached the robot: %s" % names)
        plc.close()


def test_shutdown_with_allow_shutdown():
    with running(["--log-commands"], "[commands]\nallow_shutdown = true\n") as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.trigger("power_on") == 0, "power on")
        plc.wait_di(D_POWERED_ON, 1)
        check(plc.trigger("shutdown") == 0, "shutdown refused with allow_shutdown")
        plc.expect_done("shutdown")
        check(sent(sim, "shutdown") == ['{"cmdName":"shutdown"}'], "shutdown JSON")
        plc.wait_di(D_POWERED_ON, 0, 5, "powered off by the shutdown")
        plc.close()


def test_motion_commands_with_motion_on():
    with running(["--log-commands"], MOTION_ON) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        power_and_enable(plc)
        # joint_move, absolute.
        target = [10.0, 80.0, 100.0, 5.0, 85.0, 15.0]
        check(plc.regs(H_JOINT_MOVE, f32_regs(target + [200, 100]) + [0]) == 0, "joint params")
        t = time.monotonic()
        check(plc.trigger("joint_move") == 0, "joint_move trigger")
        plc.expect_done("joint_move")
        check(sent(sim, "joint_move") ==
              ['{"cmdName":"joint_move","jointPosition":[10,80,100,5,85,15],"speed":200,'
               '"accel":100,"relFlag":0}'], "joint_move JSON %s" % sent(sim, "joint_move"))
        wait_until(lambda: close_to(plc.f32(I_JOINTS, 6), target, 1e-3) and
                   plc.di(D_INPOS)[0] == 1, 10, "the arm at the joint target")
        joint_s = time.monotonic() - t
        # end_move to a pose 20 mm below the current one.
        pose = [round(v, 1) for v in plc.f32(I_TCP, 6)]
        pose[2] -= 20
        check(plc.regs(H_END_MOVE, f32_regs(pose + [100, 100])) == 0, "end_move params")
        check(plc.trigger("end_move") == 0, "end_move trigger")
        plc.expect_done("end_move")
        check(sent(sim, "end_move") ==
              ['{"cmdName":"end_move","endPosition":%s,"speed":100,"accel":100}' % numbers(pose)],
              "end_move JSON %s" % sent(sim, "end_move"))
        wait_until(lambda: close_to(plc.f32(I_TCP, 3), pose[:3], 0.05) and
                   plc.di(D_INPOS)[0] == 1, 10, "the TCP at the end_move pose")
        # moveL, relative: 10 mm up.
        z0 = plc.f32(I_TCP + 4)[0]
        check(plc.regs(H_MOVEL, f32_regs([0, 0, 10, 0, 0, 0, 50, 100])) == 0 and
              plc.reg(H_MOVEL + 16, 1) == 0 and plc.regs(H_MOVEL + 18, f32_regs([0.5])) == 0,
              "moveL params")
        check(plc.trigger("moveL") == 0, "moveL trigger")
        plc.expect_done("moveL")
        check(sent(sim, "moveL") ==
              ['{"cmdName":"moveL","cartPosition":[0,0,10,0,0,0],"speed":50,"accel":100,'
               '"relFlag":1,"tol":0.5}'], "moveL JSON %s" % sent(sim, "moveL"))
        wait_until(lambda: abs(plc.f32(I_TCP + 4)[0] - (z0 + 10)) < 0.05 and
                   plc.di(D_INPOS)[0] == 1, 10, "the TCP 10 mm higher")
        # The mailbox and the JSON mailbox move too, with motion on.
        check(plc.mailbox(1, MAILBOX_CODE["joint_move"], HOME + [200, 100, 0]) == 0,
              "mailbox joint_move")
        state, code, msg = plc.wait_mailbox_done(1)
        check((state, code) == (DONE, 0), "mailbox joint_move result %d %d %r" % (state, code, msg))
        check(sent(sim, "joint_move")[-1] ==
              '{"cmdName":"joint_move","jointPosition":[0,90,90,0,90,0],"speed":200,'
              '"accel":100,"relFlag":0}', "mailbox joint_move JSON %s" % sent(sim, "joint_move"))
        wait_until(lambda: close_to(plc.f32(I_JOINTS, 6), HOME, 1e-3), 10, "back home")
        text = ('{"cmdName":"joint_move","relFlag":1,"jointPosition":[5,0,0,0,0,0],'
                '"speed":100,"accel":50}')
        check(plc.json_request(text) == 0, "JSON joint_move refused with motion on")
        check(plc.json_result()["state"] == DONE, "JSON joint_move result")
        check(sent(sim, "joint_move")[-1] == text, "JSON text not sent as written")
        wait_until(lambda: close_to(plc.f32(I_JOINTS, 1), [5.0], 1e-3), 10, "joint 1 at 5 deg")
        print("  joint_move reached its target in %.2f s" % joint_s)
        plc.close()


# ---- validation: refused with 03, nothing sent ----

def test_invalid_values_are_refused_and_never_sent():
    with running(["--log-commands"], MOTION_ON) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.reg(H_RAPID_RATE, 400) == 0, "rapid rate 400")
        plc.expect_done("rapid_rate")
        check(plc.reg(H_RAPID_RATE, 1500) == EX_INVALID, "rapid rate 1500 not refused with 03")
        check(plc.hr(H_RAPID_RATE) == [400], "the refused rapid rate stayed in the register")
        # An empty program name.
        check(plc.program_name("") == 0, "empty name write")
        check(plc.trigger("load_program") == EX_INVALID, "load with no name not refused")
        state, _, msg = plc.result("load_program")
        check(state == INVALID and msg, "load_program result %d %r" % (state, msg))
        # Bytes that are not UTF-8, and control characters.
        check(plc.program_name("good.jks") == 0, "good name")
        for bad in (b"\xff\xfeprog.jks", b"prog\x01.jks", b"caf\xc3", b"\xc0\xafetc"):
            check(plc.regs(H_PROGRAM_NAME, text_regs(bad, PROGRAM_NAME_REGS)) == EX_INVALID,
                  "program name %r not refused" % bad)
        check(plc.hr(H_PROGRAM_NAME, 4) == text_regs("good.jks", 4), "a refused name stayed")
        # NaN and infinity where a float target goes.
        nan_regs = [0x7FC0, 0x0000]
        check(plc.regs(H_JOINT_MOVE, nan_regs) == EX_INVALID, "NaN joint target accepted")
        check(plc.regs(H_CABINET_AO, nan_regs) == EX_INVALID, "NaN analog output accepted")
        check(plc.regs(H_MOVEL, [0x7F80, 0x0000]) == EX_INVALID, "+inf moveL target accepted")
        check(plc.regs(H_PAYLOAD_MASS, f32_regs([-1.0])) == EX_INVALID, "negative mass accepted")
        check(plc.mailbox(1, MAILBOX_CODE["rapid_rate"], [float("nan")]) == EX_INVALID,
              "NaN mailbox argument accepted")
        check(plc.mailbox(1, 99) == EX_INVALID, "unknown mailbox code accepted")
        check(plc.mailbox(1, MAILBOX_CODE["set_digital_output"], [0, 2.5, 1]) == EX_INVALID,
              "index 2.5 accepted")
        check(plc.ir(I_MAILBOX_ACK)[0] == 0, "a refused mailbox write acknowledged")
        check(plc.json_request("not json") == EX_INVALID, "a non-JSON request sent")
        check(plc.json_request('{"errorCode":"0"}') == EX_INVALID, "a request without cmdName")
        check(plc.regs(H_JSON_REQUEST, text_regs(b'{"cmdName":"get_version\xff"}',
                                                  JSON_REQUEST_REGS)) == EX_INVALID,
              "a non-UTF-8 JSON request accepted")
        fence(plc, sim)
        names = [c[1] for c in robot_commands(sim)]
        check(len(sent(sim, "rapid_rate")) == 1 and "load_program" not in names and
              "joint_move" not in names and "moveL" not in names and
              "set_analog_output" not in names and "set_digital_output" not in names and
              None not in names, "refused writes reached the robot: %s" % names)
        plc.close()


# ---- the exactly-once mailbox ----

def test_mailbox_runs_each_sequence_number_once():
    with running(["--log-commands"], NO_HEARTBEAT) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        values = [MAILBOX_CODE["power_on"]] + f32_regs([0.0] * 12) + [1]
        request = mbap(77, struct.pack(">BHHB", 16, H_MAILBOX, 26, 52)
                       + struct.pack(">26H", *values))
        first = raw_client(gw.modbus_port)
        first.sendall(request)
        check(recv_adu(first)[2][:1] == b"\x10", "mailbox FC16 refused")
        check(plc.ir(I_MAILBOX_ACK)[0] == 1, "ack_seq not 1 at once")
        state, code, _ = plc.wait_mailbox_done(1)
        check((state, code) == (DONE, 0), "mailbox power_on result %d %d" % (state, code))
        plc.wait_di(D_POWERED_ON, 1)
        first.sendall(request)  # the same request again, on the same connection
        check(recv_adu(first)[2][:1] == b"\x10", "repeated FC16 refused")
        first.close()
        second = raw_client(gw.modbus_port)  # a PLC that reconnected and retransmits
        second.sendall(request)
        check(recv_adu(second)[2][:1] == b"\x10", "retransmitted FC16 refused")
        second.close()
        fence(plc, sim)
        check(sent(sim, "power_on") == ['{"cmdName":"power_on"}'],
              "power_on sent %d times for one sequence number" % len(sent(sim, "power_on")))
        check(plc.ir(I_MAILBOX_ACK, 2) == [1, 1], "ack/done moved on a repeat")
        # The robot's refusal through the mailbox.
        check(plc.mailbox(2, MAILBOX_CODE["resume_program"]) == 0, "resume write")
        state, code, msg = plc.wait_mailbox_done(2)
        check((state, code, msg) == (ROBOT_ERROR, 2, "no program is paused"),
              "mailbox refusal shows %d %d %r" % (state, code, msg))
        plc.close()


def test_mailbox_codes_send_their_commands():
    """Each mailbox code, with its arguments, becomes the command the
    manual describes."""
    with running(["--log-commands"], NO_HEARTBEAT) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.program_name("box/mailbox.jks") == 0, "program name")
        calls = [
            ("power_on", [], '{"cmdName":"power_on"}', DONE),
            ("enable_robot", [], '{"cmdName":"enable_robot"}', DONE),
            ("load_program", [], '{"cmdName":"load_program","programName":"box/mailbox.jks"}',
             DONE),
            ("play_program", [], '{"cmdName":"play_program"}', DONE),
            ("pause_program", [], '{"cmdName":"pause_program"}', DONE),
            ("resume_program", [], '{"cmdName":"resume_program"}', DONE),
            ("stop_program", [], '{"cmdName":"stop_program"}', DONE),
            ("rapid_rate", [0.4], '{"cmdName":"rapid_rate","rate_value":0.4}', DONE),
            ("set_digital_output", [0, 3, 1],
             '{"cmdName":"set_digital_output","type":0,"index":3,"value":1}', DONE),
            ("set_analog_output", [2, 5, 1.25],
             '{"cmdName":"set_analog_output","type":2,"index":5,"value":1.25}', DONE),
            ("set_tool_id", [6], '{"cmdName":"set_tool_id","tool_id":6}', DONE),
            ("set_clsn_sensitivity", [4],
             '{"cmdName":"set_clsn_sensitivity","sensitivityVal":4}', DONE),
            ("set_payload", [1.5, 1, 2, 3.25],
             '{"cmdName":"set_payload","mass":1.5,"centroid":[1,2,3.25]}', DONE),
            ("clear_error", [], '{"cmdName":"clear_error"}', DONE),
            ("disable_robot", [], '{"cmdName":"disable_robot"}', DONE),
            ("power_off", [], '{"cmdName":"power_off"}', DONE),
        ]
        for seq, (name, args, want, outcome) in enumerate(calls, 1):
            check(plc.mailbox(seq, MAILBOX_CODE[name], args) == 0, "mailbox %s refused" % name)
            state, code, msg = plc.wait_mailbox_done(seq)
            got = sent(sim, name)
            check(got and got[-1] == want, "mailbox %s sent %s, expected %s" % (name, got, want))
            check(state == outcome, "mailbox %s: state %d code %d %r" % (name, state, code, msg))
            if name == "play_program":
                wait_until(lambda: plc.ir(I_INTERP_STATE)[0] == 3, 5, "running")
        wait_until(lambda: plc.ir(I_RAPIDRATE_PERMILLE)[0] == 400 and plc.ir(I_TOOL_ID)[0] == 6
                   and plc.di(D_DOUT + 3)[0] == 1 and plc.f32(I_EXTIO_AO + 10)[0] == 1.25
                   and plc.di(D_POWERED_ON)[0] == 0, 5, "the status to show the mailbox's work")
        plc.close()


def test_mailbox_commands_refresh_the_robot_information():
    with running(["--log-commands"], NO_HEARTBEAT) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        power_and_enable(plc)
        check(plc.program_name("box/refresh.jks") == 0, "program name")
        check(plc.mailbox(1, MAILBOX_CODE["load_program"]) == 0, "mailbox load_program")
        check(plc.wait_mailbox_done(1)[0] == DONE, "load_program through the mailbox")
        check(plc.mailbox(2, MAILBOX_CODE["play_program"]) == 0, "mailbox play_program")
        check(plc.wait_mailbox_done(2)[0] == DONE, "play_program through the mailbox")
        check(plc.json_request('{"cmdName":"set_clsn_sensitivity","sensitivityVal":1}') == 0,
              "JSON set_clsn_sensitivity")
        check(plc.json_result()["state"] == DONE, "set_clsn_sensitivity through the JSON mailbox")
        plc.wait_ir(I_INTERP_STATE, 3, 5, "the program running in the status")
        fence(plc, sim)
        want = ("box/refresh.jks", PROGRAM_RUNNING, 1)

        def info():
            return (plc.text(I_LOADED_PROGRAM, 32), plc.ir(I_PROGRAM_STATE)[0],
                    plc.ir(I_COLLISION_LEVEL)[0])

        try:
            wait_until(lambda: info() == want, 3, "the robot information")
        except TestFailure:
            raise TestFailure("loaded_program, program_state, collision_level read %r, "
                              "expected %r" % (info(), want)) from None
        plc.close()


def test_busy_mailbox_and_trigger_refuse_with_06():
    with running(["--log-commands", "--reply-delay-ms", "1000",
                  "--delay-command", "power_on"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        check(plc.mailbox(1, MAILBOX_CODE["power_on"]) == 0, "first mailbox command")
        check(plc.ir(I_MAILBOX_STATE)[0] == PENDING, "first command not pending")
        check(plc.mailbox(2, MAILBOX_CODE["power_off"]) == EX_BUSY,
              "a second mailbox command while the first is pending: not exception 06")
        check(plc.ir(I_MAILBOX_ACK)[0] == 1, "the refused command was acknowledged")
        state, _, _ = plc.wait_mailbox_done(1)
        check(state == DONE, "first mailbox command result %d" % state)
        fence(plc, sim)
        check(sent(sim, "power_off") == [], "the refused mailbox command was sent")
        check(plc.mailbox(2, MAILBOX_CODE["power_off"]) == 0, "the same command once free")
        plc.wait_mailbox_done(2)
        check(len(sent(sim, "power_off")) == 1, "power_off after the retry")
        # A trigger whose command is still pending.
        check(plc.trigger("power_on") == 0, "power_on trigger")
        check(plc.coil(TRIGGER["power_on"], 0) == 0, "re-arm while pending")
        check(plc.coil(TRIGGER["power_on"], 1) == EX_BUSY, "trigger while pending: not 06")
        check(plc.read_coils(TRIGGER["power_on"])[0] == 0, "the refused 1 stayed in the coil")
        # The count moved for the refused trigger: the result is its own,
        # also once the pending one has been answered.
        check(plc.result("power_on") == (REFUSED, 0, "busy: the previous one is pending"),
              "refused trigger's result: %r" % (plc.result("power_on"),))
        fence(plc, sim)
        check(plc.result("power_on")[0] == REFUSED, "the pending one's result replaced it")
        check(len(sent(sim, "power_on")) == 2, "power_on sent %d times, expected 2"
              % len(sent(sim, "power_on")))
        plc.close()


# ---- the command link's faults ----

TIMEOUT_CONFIG = "[commands]\nreply_timeout_ms = 400\n"
LATE_REPLY = ["--log-commands", "--reply-delay-ms", "3000", "--delay-command", "power_off"]


def test_reply_timeout_of_a_command_sent_to_an_idle_queue():
    with running(LATE_REPLY, TIMEOUT_CONFIG) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        t0 = time.monotonic()
        check(plc.trigger("power_off") == 0, "power_off")
        try:
            wait_until(lambda: plc.ir(RESULT["power_off"])[0] != PENDING, 2.0, "a result")
        except TestFailure:
            pass
        state, code, msg = plc.result("power_off")
        check(state == TIMEOUT and "400 ms" in msg,
              "reply_timeout_ms = 400; %.1f s after sending, power_off's result is %d %d %r"
              % (time.monotonic() - t0, state, code, msg))
        plc.close()


def test_reply_timeout_then_late_reply_never_answers_the_next_command():
    """power_on and power_off in one FC15: power_off leaves the queue when
    power_on's reply comes, its reply is 3 s late, the timeout is 400 ms.
    The next command must get its own reply, never the late one."""
    with running(LATE_REPLY, TIMEOUT_CONFIG) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        t0 = time.monotonic()
        check(plc.coils(TRIGGER["power_on"], [1, 1]) == 0, "power_on and power_off in one write")
        plc.expect_done("power_on")
        state, code, msg = plc.wait_result("power_off", 10)
        timed_out = time.monotonic() - t0
        check(state == TIMEOUT and "400 ms" in msg,
              "power_off result %d %d %r" % (state, code, msg))
        check(timed_out > 0.35, "timed out after %.3f s, before 400 ms" % timed_out)
        # The link was restarted so that the late reply cannot arrive on it.
        wait_until(lambda: plc.u32(I_COMMAND_RECONNECTS) >= 1, 10, "the command link restarted")
        plc.ready()
        # The robot did power off (only its reply is late), so enable is
        # refused: its own reply, not power_off's late errorCode "0".
        check(plc.trigger("enable_robot") == 0, "enable")
        state, code, msg = plc.wait_result("enable_robot")
        next_at = time.monotonic() - t0
        check((state, code, msg) == (ROBOT_ERROR, 2, "robot is powered off"),
              "enable after the timeout: %d %d %r" % (state, code, msg))
        check(plc.json_request('{"cmdName":"get_version"}') == 0, "JSON get_version")
        reply = plc.json_result()
        check(json.loads(reply["reply"]).get("cmdName") == "get_version",
              "the JSON mailbox got %r" % reply["reply"])
        wait_until(lambda: "delayed reply to power_off" in sim.output(), 10, "the late reply")
        late = [line for line in sim.output().splitlines() if "delayed reply to power_off" in line]
        check("dropped: its client has gone" in late[0], "the late reply went out: %s" % late)
        check(plc.result("power_off")[0] == TIMEOUT, "power_off no longer says timeout")
        check(plc.result("enable_robot")[:2] == (ROBOT_ERROR, 2), "enable's result changed")
        check("no command in flight" not in gw.output(), "a stray reply reached the gateway")
        check(len(sent(sim, "power_off")) == 1, "power_off was resent")
        check(next_at < 3.0, "the next command was answered %.2f s after the first: after "
              "the late reply was due, so the test proved nothing" % next_at)
        print("  timeout after %.2f s; the next command answered %.2f s after the first "
              "(the late reply due at about 3 s)" % (timed_out, next_at))
        plc.close()


def test_link_down_refuses_with_0B_and_nothing_is_sent_after_reconnect():
    config = "[robot]\nreconnect_min_ms = 50\nreconnect_max_ms = 300\n"
    first = Sim("--log-commands", "--reply-delay-ms", "5000", "--delay-command", "power_off")
    second = gw = None
    try:
        gw = Gateway(first, config)
        plc = Plc(gw)
        plc.ready()
        check(plc.trigger("power_on") == 0, "power on")
        plc.expect_done("power_on")
        check(plc.trigger("power_off") == 0, "power_off")
        check(plc.result("power_off")[0] == PENDING, "power_off not pending")
        # Queued behind it: a rapid rate and a digital output.
        check(plc.reg(H_RAPID_RATE, 700) == 0 and plc.coil(C_CABINET_DO, 1) == 0, "queued")
        check(plc.result("rapid_rate")[0] == PENDING, "rapid_rate not pending")
        first.stop()
        # power_off was written: its outcome is unknown; the two queued
        # behind it never left the gateway.
        for name, expected in (("power_off", LINK_DOWN), ("rapid_rate", NOT_SENT),
                               ("set_digital_output", NOT_SENT)):
            state, _, msg = plc.wait_result(name)
            check(state == expected, "%s, accepted before the link went down: state %d %r, "
                  "expected %d" % (name, state, msg, expected))
        plc.wait_di(D_COMMAND_LINK_UP, 0)
        refusals = [
            ("power_on trigger", lambda: plc.trigger("power_on")),
            ("rapid rate", lambda: plc.reg(H_RAPID_RATE, 300)),
            ("digital output", lambda: plc.coil(C_CABINET_DO, 1)),
            ("mailbox", lambda: plc.mailbox(1, MAILBOX_CODE["enable_robot"])),
            ("JSON mailbox", lambda: plc.json_request('{"cmdName":"get_joint_pos"}')),
        ]
        for what, write in refusals:
            check(write() == EX_LINK_DOWN, "%s with the link down: not exception 0B" % what)
        check(plc.read_coils(TRIGGER["power_on"])[0] == 0, "the refused trigger reads 1")
        check(plc.result("power_on")[0] == NOT_SENT, "power_on result after the refusal")
        check(plc.ir(I_MAILBOX_ACK)[0] == 0, "the refused mailbox command was acknowledged")
        second = SimOn(first.status_port, first.command_port, "--log-commands")
        plc.ready()
        wait_until(lambda: sent(second, "get_clsn_sensitivity"), 10, "the gateway's queries")
        fence(plc, second)
        names = [c[1] for c in robot_commands(second)]
        check(all(housekeeping(n) or n == "set_tool_id" for n in names),
              "sent after the reconnect: %s" % names)
        check(plc.trigger("power_on") == 0, "power_on on the new link")
        plc.expect_done("power_on")
        check(sent(second, "power_on") == ['{"cmdName":"power_on"}'], "power_on on the new link")
        plc.close()
    finally:
        try:
            if gw:
                gw.stop()
        finally:
            if second:
                second.stop()
            if first.alive():
                first.stop()


# ---- who may write ----

def test_write_allow_refuses_other_clients_and_still_serves_their_reads():
    config = "[modbus]\nwrite_allow = 127.0.0.1\n"
    with running(["--log-commands"], config) as (sim, gw):
        allowed = Plc(gw)
        allowed.ready()
        other = Plc(gw, source="127.0.0.2")
        check(other.client.socket.getsockname()[0] == "127.0.0.2", "source address")
        check(other.coil(TRIGGER["power_on"], 1) == EX_NOT_PERMITTED,
              "write from 127.0.0.2 not refused")
        check(other.reg(H_RAPID_RATE, 100) == EX_NOT_PERMITTED, "register write not refused")
        check(other.mailbox(1, MAILBOX_CODE["power_on"]) == EX_NOT_PERMITTED, "mailbox")
        check(other.ir(I_MAGIC)[0] == 0x4A4B, "reads refused to the other client")
        check(other.di(D_COMMAND_LINK_UP)[0] == 1, "discrete inputs refused to the other client")
        fence(allowed, sim)
        check(sent(sim, "power_on") == [] and sent(sim, "rapid_rate") == [],
              "a refused client's write reached the robot")
        check(allowed.trigger("power_on") == 0, "the allowed client refused")
        allowed.expect_done("power_on")
        check(len(sent(sim, "power_on")) == 1, "power_on count")
        other.close()
        allowed.close()
    with running(["--log-commands"], "[modbus]\nread_only = true\n") as (sim, gw):
        plc = Plc(gw)
        plc.wait_di(D_COMMAND_LINK_UP, 1)
        plc.wait_di(D_STATUS_FRESH, 1)
        check(plc.coil(TRIGGER["power_on"], 1) == EX_NOT_PERMITTED,
              "read_only: trigger not refused")
        check(plc.reg(H_TOOL_ID, 3) == EX_NOT_PERMITTED, "read_only: register not refused")
        check(plc.ir(I_MAGIC)[0] == 0x4A4B and plc.di(D_STATUS_FRESH) == [1], "reads")
        wait_until(lambda: sent(sim, "get_clsn_sensitivity"), 10, "the gateway's queries")
        names = [c[1] for c in robot_commands(sim)]
        check(all(housekeeping(n) for n in names), "read_only sent %s" % names)
        plc.close()


def test_write_allow_on_a_dual_stack_bind():
    """bind = :: serves IPv4 clients as ::ffff:127.0.0.1; write_allow =
    127.0.0.1 must still let them write (it refused every write before),
    and 127.0.0.2 must still be refused."""
    config = "[modbus]\nwrite_allow = 127.0.0.1\n"
    sim = Sim("--log-commands")
    gw = None
    try:
        gw = Gateway(sim, config, extra=["--modbus-bind", "::"])
        allowed = Plc(gw)
        allowed.ready()
        check(allowed.trigger("power_on") == 0, "127.0.0.1 refused on a dual-stack bind")
        allowed.expect_done("power_on")
        other = Plc(gw, source="127.0.0.2")
        check(other.coil(TRIGGER["power_off"], 1) == EX_NOT_PERMITTED,
              "127.0.0.2 not refused on a dual-stack bind")
        check(other.ir(I_MAGIC)[0] == 0x4A4B, "reads refused to the other client")
        fence(allowed, sim)
        check(len(sent(sim, "power_on")) == 1 and sent(sim, "power_off") == [],
              "robot got %s" % [c[1] for c in robot_commands(sim)])
        other.close()
        allowed.close()
    finally:
        try:
            if gw:
                gw.stop()
        finally:
            sim.stop()


def test_mbpoll_commands_the_robot():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()

        def mbpoll(kind, ref, value):
            return subprocess.run(["mbpoll", "-m", "tcp", "-p", str(gw.modbus_port), "-t", kind,
                                   "-r", str(ref + 1), "-1", "127.0.0.1", str(value)],
                                  capture_output=True, text=True, timeout=20)

        out = mbpoll("0", TRIGGER["power_on"], 1)
        check(out.returncode == 0, "mbpoll coil write failed: %s %s" % (out.stdout, out.stderr))
        plc.expect_done("power_on")
        plc.wait_di(D_POWERED_ON, 1)
        out = mbpoll("4", H_RAPID_RATE, 300)
        check(out.returncode == 0, "mbpoll register write: %s %s" % (out.stdout, out.stderr))
        plc.wait_ir(I_RAPIDRATE_PERMILLE, 300)
        out = mbpoll("4", H_RAPID_RATE, 1500)
        check(out.returncode != 0 and "Illegal data value" in out.stdout + out.stderr,
              "mbpoll was not told 'Illegal data value': %s %s" % (out.stdout, out.stderr))
        check(sent(sim, "power_on") == ['{"cmdName":"power_on"}'] and
              sent(sim, "rapid_rate") == ['{"cmdName":"rapid_rate","rate_value":0.3}'],
              "sent %s %s" % (sent(sim, "power_on"), sent(sim, "rapid_rate")))
        plc.close()


# ---- the JSON mailbox ----

def test_json_mailbox_round_trips():
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        joints = [10, 80, 100, 5, 85, 15]
        # A request of exactly 240 bytes, the whole block, goes out whole.
        text = '{"cmdName":"kine_forward","jointPosition":[10,80,100,5,85,15]}'
        text = text[:-1] + " " * (240 - len(text)) + "}"
        check(plc.json_request(text) == 0, "kine_forward")
        r = plc.json_result()
        check(sent(sim, "kine_forward") == [text], "the 240-byte request was not sent whole")
        check((r["state"], r["code"], r["truncated"]) == (DONE, 0, 0), "kine_forward %r" % r)
        check(r["reply"] == replies(sim, "kine_forward")[0] and
              r["length"] == len(r["reply"].encode()), "reply text or length differs: %r" % r)
        cart = json.loads(r["reply"])["cartPosition"]
        request = json.dumps({"cmdName": "kine_inverse", "jointPosition": HOME,
                              "cartPosition": cart})
        check(plc.json_request(request) == 0, "kine_inverse")
        r = plc.json_result()
        check(r["state"] == DONE and sent(sim, "kine_inverse") == [request], "kine_inverse %r" % r)
        check(close_to(json.loads(r["reply"])["jointPosition"], joints, 1e-3),
              "inverse of forward: %s" % r["reply"])
        check(plc.json_request('{"cmdName":"get_joint_pos"}') == 0, "get_joint_pos")
        r = plc.json_result()
        check(close_to(json.loads(r["reply"])["joint_pos"], plc.f32(I_JOINTS, 6), 1e-4),
              "get_joint_pos %s against the status" % r["reply"])
        # get_data: the whole status, longer than the reply block.
        check(plc.json_request('{"cmdName":"get_data"}') == 0, "get_data")
        r = plc.json_result()
        logged = [line for line in sim.output().splitlines() if '"cmdName":"get_data"' in line]
        length = int(logged[-1].rsplit("(", 1)[1].split()[0])
        check(r["state"] == DONE and r["truncated"] == 1 and r["length"] == length,
              "get_data: state %d truncated %d length %d (sent %d)"
              % (r["state"], r["truncated"], r["length"], length))
        check(len(r["reply"]) == 2 * JSON_REPLY_REGS and r["reply"].startswith(
            '{"errorCode": "0", "errorMsg": "", "cmdName": "get_data", "data": {"len": '),
            "get_data reply block %r" % r["reply"][:120])
        # Refusals by the robot, through the JSON mailbox.
        check(plc.json_request('{"cmdName":"kine_inverse","jointPosition":[0,90,90,0,90,0],'
                               '"cartPosition":[5000,0,0,0,0,0]}') == 0, "unreachable pose")
        r = plc.json_result()
        check((r["state"], r["code"], r["msg"]) == (ROBOT_ERROR, 2, "call kine inverse failed"),
              "unreachable pose %r" % r)
        # A name the command table does not know could be motion: refused
        # with motion off, and never sent.
        check(plc.json_request('{"cmdName":"no_such_command"}') == EX_NOT_PERMITTED,
              "unknown command accepted with motion off")
        check(not sent(sim, "no_such_command"), "the unknown command reached the robot")
        print("  get_data reply of %d bytes: the first %d readable, truncated flag set"
              % (length, 2 * JSON_REPLY_REGS))
        plc.close()


def smuggle(text, moving_name):
    """With motion off: the JSON mailbox's request 'text' must not move the
    robot. Returns (exception, commands the robot got, joints moved)."""
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        power_and_enable(plc)
        before = plc.f32(I_JOINTS, 6)
        ex = plc.json_request(text)
        if ex == 0:
            plc.json_result()
        fence(plc, sim)
        moved = False
        if sent(sim, moving_name):
            try:
                wait_until(lambda: not close_to(plc.f32(I_JOINTS, 6), before, 1e-3), 3, "motion")
                moved = True
            except TestFailure:
                pass
        names = [c[1] for c in robot_commands(sim)]
        plc.close()
    check(ex in (EX_NOT_PERMITTED, EX_INVALID) and moving_name not in names and not moved,
          "motion off, request %s: exception %d; the robot got %s; joints moved: %s"
          % (text, ex, [n for n in names if not housekeeping(n)], moved))


def test_json_mailbox_refuses_a_second_object_in_the_text():
    smuggle('{"cmdName":"get_version"}{"cmdName":"joint_move","relFlag":1,'
            '"jointPosition":[20,0,0,0,0,0],"speed":100,"accel":100}', "joint_move")


def test_json_mailbox_refuses_a_repeated_cmdName():
    smuggle('{"cmdName":"get_version","cmdName":"joint_move","relFlag":1,'
            '"jointPosition":[20,0,0,0,0,0],"speed":100,"accel":100}', "joint_move")


def test_json_mailbox_refuses_a_motion_name_the_table_does_not_know():
    """Joint_Move is not joint_move to the command table: it reached the
    robot with motion off. Now it is refused (01) and nothing is sent."""
    smuggle('{"cmdName":"Joint_Move","relFlag":1,"jointPosition":[20,0,0,0,0,0],'
            '"speed":100,"accel":100}', "Joint_Move")


def test_a_plc_text_cannot_forge_a_log_line():
    """The JSON mailbox's cmdName is the PLC's text: with a newline, a
    forged "<3>jakagw:" entry and escape sequences in it, the refusal's log
    line is still one line, with the bytes escaped and the Chinese kept."""
    name = "程序\n<3>jakagw: forged\r\u001b[2J\u009b"
    with running(["--log-commands"]) as (sim, gw):
        plc = Plc(gw)
        plc.ready()
        ex = plc.json_request(json.dumps({"cmdName": name}, ensure_ascii=False))
        check(ex == EX_NOT_PERMITTED, "exception %r" % ex)
        plc.close()
        wait_until(lambda: log_lines(gw, "JSON mailbox: refused"), 5, "the log line")
        out = gw.output()
    lines = [l for l in out.splitlines() if "forged" in l]
    check(len(lines) == 1 and lines[0].startswith("<5>JSON mailbox: refused cmdName"),
          "forged text on %d lines: %r" % (len(lines), lines))
    check('"程序\\x0a<3>jakagw: forged\\x0d\\x1b[2J\\u009b"' in lines[0],
          "not escaped as expected: %r" % lines[0])
    check("\x1b" not in out and "\r" not in out and "\u009b" not in out,
          "a control character reached the log")


def test_json_mailbox_treats_payload_identification_as_motion():
    smuggle('{"cmdName":"start_torq_sensor_payload_identify",'
            '"jointPosition":[20,90,90,90,0,90]}', "start_torq_sensor_payload_identify")


# ---- the simulator answers what the gateway sends ----

def test_simulator_extension_io_get_data_and_repeated_members():
    sim = Sim()
    try:
        s = socket.create_connection(("127.0.0.1", sim.command_port), timeout=5)
        decoder = json.JSONDecoder()
        buf, size = b"", 0

        def call(text):
            """One reply, and the reads of at most 1 KiB it took."""
            nonlocal buf, size
            s.sendall(text.encode())
            reads = 0
            while True:
                try:
                    obj, end = decoder.raw_decode(buf.decode())
                    buf, size = buf.decode()[end:].encode(), end
                    return obj, reads
                except ValueError:
                    chunk = s.recv(1024)
                    check(chunk, "command port closed")
                    buf += chunk
                    reads += 1

        reply, reads = call('{"cmdName":"get_data"}')
        get_data_size = size
        data = reply.get("data", {})
        check(reply["errorCode"] == "0" and reply["cmdName"] == "get_data" and
              data.get("len") and "joint_actual_position" in data and reads > 4,
              "get_data: %d reads, members %s" % (reads, sorted(reply)))
        check(call('{"cmdName":"set_digital_output","type":2,"index":15,"value":1}')[0]
              ["errorCode"] == "0", "extension DO 15")
        check(call('{"cmdName":"set_digital_output","type":2,"index":16,"value":1}')[0]
              ["errorCode"] == "2", "extension DO 16 (the module has 16) accepted")
        check(call('{"cmdName":"set_analog_output","type":2,"index":7,"value":-4.5}')[0]
              ["errorCode"] == "0", "extension AO 7")
        check(call('{"cmdName":"set_analog_output","type":2,"index":8,"value":1}')[0]
              ["errorCode"] == "2", "extension AO 8 (the module has 8) accepted")
        reply, _ = call('{"cmdName":"get_version","cmdName":"get_joint_pos"}')
        check(reply["cmdName"] == "get_joint_pos", "a repeated member: the first counted")
        doc = call('{"cmdName":"get_data"}')[0]["data"]
        extio = doc["extio"]["status"]
        check(extio[1][15] == 1 and sum(extio[1]) == 1 and extio[3][7] == -4.5 and
              doc["extio"]["setup"][0][3][1] == [0, 16], "extio after the commands: %s" % extio)
        s.close()
        print("  get_data reply of %d bytes came in %d reads of at most 1 KiB"
              % (get_data_size, reads))
    finally:
        sim.stop()


if __name__ == "__main__":
    run([test_addresses_match_the_register_map,
         test_simulator_extension_io_get_data_and_repeated_members,
         test_power_enable_disable_clear_error_by_trigger_coils,
         test_robot_refusal_surfaces_its_code_and_message, test_a_robot_message_cannot_forge_a_log_line,
         test_a_plc_text_cannot_forge_a_log_line, test_write_allow_on_a_dual_stack_bind,
         test_json_mailbox_refuses_a_motion_name_the_table_does_not_know,
         test_program_recipe_as_a_plc_runs_it,
         test_setpoints_rapid_rate_tool_frame_collision_level,
         test_set_user_id_selects_the_user_frame,
         test_digital_outputs_cabinet_tool_and_extension,
         test_setpoint_result_waits_for_the_last_of_a_multiple_write,
         test_analog_outputs_cabinet_and_extension,
         test_set_payload_with_its_parameters,
         test_shutdown_and_motion_refused_by_default,
         test_shutdown_with_allow_shutdown,
         test_motion_commands_with_motion_on,
         test_invalid_values_are_refused_and_never_sent,
         test_mailbox_runs_each_sequence_number_once,
         test_mailbox_codes_send_their_commands,
         test_mailbox_commands_refresh_the_robot_information,
         test_busy_mailbox_and_trigger_refuse_with_06,
         test_reply_timeout_of_a_command_sent_to_an_idle_queue,
         test_reply_timeout_then_late_reply_never_answers_the_next_command,
         test_link_down_refuses_with_0B_and_nothing_is_sent_after_reconnect,
         test_write_allow_refuses_other_clients_and_still_serves_their_reads,
         test_mbpoll_commands_the_robot,
         test_json_mailbox_round_trips,
         test_json_mailbox_refuses_a_second_object_in_the_text,
         test_json_mailbox_refuses_a_repeated_cmdName,
         test_json_mailbox_treats_payload_identification_as_motion])
