#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The PLC contract as a PLC program meets it, through pymodbus against the
real jakagw and jakasim (--log-commands: what reached the robot):

- every trigger and mailbox write handled changes its count, whatever its
  outcome; a trigger coil left at 1 is, from the connection that set it, a
  retransmission (nothing sent), from any other (a restarted PLC, a
  reconnect) refused with its reason, and a relative move never reaches
  the robot twice because a connection dropped and came back;
- what a PLC writes is what is sent: the moveL block (HR 340-359, HR 357
  unassigned) in one FC16; a motion trigger whose target was never
  written sends nothing; the exactly-once mailbox runs only when code,
  arguments and sequence come in one write;
- the write owner is a PLC, not a socket ([network_exception] owner);
- no program start and no motion before the PLC heartbeat was seen
  changing ([network_exception] require_heartbeat), and the PLC, the page
  and /status.json can see why;
- every reason whole in its 40 bytes; the JSON mailbox's reply cleared by a
  refusal; each output coil's read-back input named in the register map,
  and the robot's status showing the output there.
"""
import http.client
import json
import struct

from harness import (Gateway, ModbusPlc, Sim, check, free_port, map_rows, port_open, run,
                     sim_commands, wait_until)

# Addresses, as the register map gives them (checked against it below).
C_JOINT_MOVE, C_MOVEL, C_PLAY, C_POWER_ON, C_JSON_TRIGGER = 112, 114, 107, 100, 120
C_STOP, H_RAPID_RATE = 110, 100
C_CABINET_DO_1, C_TOOL_DO_0 = 200, 216
H_HEARTBEAT, H_JOINT_MOVE, H_MOVEL, H_MAILBOX, H_MAILBOX_SEQ = 0, 300, 340, 400, 425
H_PROGRAM_NAME, H_JSON_REQUEST = 200, 500
D_COMMAND_LINK_UP, D_STATUS_FRESH, D_INPOS = 1, 2, 19
I_WRITE_OWNER, I_ROBOT_HANDLE, I_RAPIDRATE_PERMILLE = 66, 64, 114
RESULT = {"power_on": 4000, "play_program": 4168, "joint_move": 4432, "moveL": 4480,
          "stop_program": 4240}
I_MAILBOX_ACK, I_MAILBOX_STATE, I_MAILBOX_COUNT = 4600, 4602, 4625
I_JSON_STATE, I_JSON_LENGTH, I_JSON_COUNT, I_JSON_REPLY = 4650, 4674, 4676, 4700
I_PLC_HEARTBEAT_STATE = 5603
PENDING, DONE, INVALID, REFUSED = 1, 2, 6, 7
EX_NOT_PERMITTED, EX_ADDRESS, EX_INVALID = 0x01, 0x02, 0x03
CODE_RAPID_RATE = 20

# The heartbeat is written once; its limit is long enough that it never
# expires during a test (the loss itself is test_policy.py's).
CONTRACT = "[commands]\nmotion = true\n[network_exception]\ntime_limit_ms = 600000\n"


def f32_regs(values):
    return list(struct.unpack(">%dH" % (2 * len(values)),
                              struct.pack(">%df" % len(values), *values)))


def regs_text(regs):
    return b"".join(struct.pack(">H", r) for r in regs).rstrip(b"\0").decode("utf-8")


class Plc(ModbusPlc):
    def __init__(self, gw):
        super().__init__(gw.modbus_port)
        self.beat = 0

    def heartbeat(self):
        self.beat += 1
        check(self.reg(H_HEARTBEAT, self.beat) == 0, "heartbeat write refused")

    def ready(self):
        wait_until(lambda: self.di(D_COMMAND_LINK_UP)[0] == 1 and
                   self.di(D_STATUS_FRESH)[0] == 1 and self.ir(I_ROBOT_HANDLE)[0] == 2,
                   15, "the command link, fresh status and the robot's handler")

    def result(self, name):
        regs = self.ir(RESULT[name], 24)
        return {"state": regs[0], "msg": regs_text(regs[3:23]), "count": regs[23]}

    def wait_done(self, name):
        wait_until(lambda: self.ir(RESULT[name])[0] != PENDING, 10, "%s's result" % name)
        r = self.result(name)
        check(r["state"] == DONE, "%s: %r" % (name, r))
        return r

    def power_and_enable(self):
        for coil in (100, 102):
            check(self.pulse(coil) == 0, "power/enable refused")
        wait_until(lambda: self.di(17)[0] == 1, 10, "the robot enabled")


def sent(sim, name):
    return sim_commands(sim, name)


def started(config=CONTRACT, sim_args=("--log-commands",)):
    sim = Sim(*sim_args)
    try:
        gw = Gateway(sim, config)
    except Exception:
        sim.stop(None)
        raise
    return sim, gw


def stop(sim, gw, *plcs):
    for plc in plcs:
        plc.close()
    try:
        gw.stop()
    finally:
        sim.stop()


# ---- item 3: a result a PLC can match to its own request ----

def test_trigger_left_at_1_retransmitted_or_refused_never_sent_twice():
    sim, gw = started()
    a = Plc(gw)
    b = None
    try:
        a.ready()
        a.heartbeat()
        a.power_and_enable()
        # A relative joint move: 5 degrees on joint 1.
        check(a.regs(H_JOINT_MOVE, f32_regs([5, 0, 0, 0, 0, 0, 30, 100]) + [1]) == 0,
              "joint_move parameters")
        before = a.result("joint_move")["count"]
        check(a.pulse(C_JOINT_MOVE) == 0, "joint_move trigger")
        first = a.wait_done("joint_move")
        check(first["count"] == (before + 1) & 0xFFFF, "count after the trigger: %r" % first)
        # The same connection's 1 again (a retransmission): answered,
        # nothing sent, nothing counted.
        check(a.coil(C_JOINT_MOVE, 1) == 0, "retransmitted 1 refused")
        check(a.result("joint_move")["count"] == first["count"], "a retransmission counted")
        # The PLC restarts mid-handshake: a new connection writes 1 onto
        # the trigger its predecessor left at 1.
        a.close()
        b = Plc(gw)
        ex = b.coil(C_JOINT_MOVE, 1)
        r = b.result("joint_move")
        print("  a reconnected PLC's 1 onto a trigger left at 1: exception %02x, result %r"
              % (ex, r))
        check(ex == EX_NOT_PERMITTED, "a 1 onto a trigger left at 1 answered %02x" % ex)
        check(r["msg"] == "trigger still 1: write 0 first" and r["state"] == REFUSED,
              "its result: %r" % r)
        check(r["count"] == (first["count"] + 1) & 0xFFFF, "its count did not change: %r" % r)
        # 0, then 1, as the guide says: a new command, counted.
        b.heartbeat()
        check(b.pulse(C_JOINT_MOVE) == 0, "joint_move after re-arming")
        check(b.wait_done("joint_move")["count"] == (first["count"] + 2) & 0xFFFF,
              "count after the re-armed trigger")
        moves = sent(sim, "joint_move")
        check(len(moves) == 2 and all(m["relFlag"] == 1 for m in moves),
              "relative joint moves sent: %r (two triggers 0 -> 1)" % moves)
    finally:
        stop(sim, gw, *[p for p in (a, b) if p])


# ---- item 4: what a PLC writes is what is sent ----

def test_movel_block_in_one_fc16_and_no_move_to_a_target_never_written():
    sim, gw = started()
    plc = Plc(gw)
    try:
        plc.ready()
        plc.heartbeat()
        plc.power_and_enable()
        # A fresh gateway: no target written, nothing sent.
        for name, coil in (("joint_move", C_JOINT_MOVE), ("moveL", C_MOVEL)):
            ex = plc.pulse(coil)
            r = plc.result(name)
            print("  %s with no target written: exception %02x, %r" % (name, ex, r))
            check(ex == EX_INVALID and r["msg"] == "target not written" and r["count"] == 1,
                  "%s with no target: exception %02x, %r" % (name, ex, r))
        check(not sent(sim, "joint_move") and not sent(sim, "moveL"),
              "a move to a target nobody wrote reached the robot")
        # The whole moveL block, 340..359, in one FC16 (357 unassigned):
        # relative, 10 mm up.
        block = f32_regs([0, 0, 10, 0, 0, 0, 50, 100]) + [1, 0xBEEF] + f32_regs([0.5])
        check(len(block) == 20, "block size")
        ex = plc.regs(H_MOVEL, block)
        print("  moveL block HR 340-359 in one FC16: %s" % ("accepted" if ex == 0 else
                                                             "exception %02x" % ex))
        check(ex == 0, "the moveL block in one FC16: exception %02x" % ex)
        check(plc.hr(357)[0] == 0, "the unassigned register kept what was written")
        check(plc.pulse(C_MOVEL) == 0, "moveL trigger")
        plc.wait_done("moveL")
        check(sent(sim, "moveL") == [{"cmdName": "moveL", "cartPosition": [0, 0, 10, 0, 0, 0],
                                      "speed": 50, "accel": 100, "relFlag": 1, "tol": 0.5}],
              "moveL sent: %r" % sent(sim, "moveL"))
        # HR 357 alone is still no register.
        check(plc.reg(357, 1) == EX_ADDRESS, "HR 357 alone accepted")
        # A refused write to the target (not finite): the trigger is
        # refused, not sent with the old target.
        wait_until(lambda: plc.di(D_INPOS)[0] == 1, 10, "the arm in position")
        check(plc.regs(H_MOVEL, [0x7F80, 0]) == EX_INVALID, "+inf accepted")
        check(plc.pulse(C_MOVEL) == EX_INVALID and
              plc.result("moveL")["msg"] == "target not written", "moveL after a refused target")
        check(len(sent(sim, "moveL")) == 1, "moveL sent after its target write was refused")
    finally:
        stop(sim, gw, plc)


def test_mailbox_sequence_alone_is_refused():
    sim, gw = started()
    plc = Plc(gw)
    try:
        plc.ready()
        rate = plc.ir(I_RAPIDRATE_PERMILLE)[0]
        # Code, then the sequence, each on its own (FC06): the argument
        # would be whatever was left, 0 on a fresh gateway.
        check(plc.reg(H_MAILBOX, CODE_RAPID_RATE) == 0, "mailbox code")
        ex = plc.reg(H_MAILBOX_SEQ, 1)
        regs = plc.ir(I_MAILBOX_STATE, 23)
        msg = regs_text(regs[3:23])
        print("  mailbox sequence written alone: exception %02x, %r; rapid_rate sent: %r"
              % (ex, msg, sent(sim, "rapid_rate")))
        check(ex == EX_INVALID and msg == "write code, args and seq in one write",
              "a sequence alone: exception %02x, %r" % (ex, msg))
        check(plc.ir(I_MAILBOX_COUNT)[0] == 1 and plc.ir(I_MAILBOX_ACK)[0] == 0,
              "count %d, ack %d" % (plc.ir(I_MAILBOX_COUNT)[0], plc.ir(I_MAILBOX_ACK)[0]))
        # Whole, in one write: it runs.
        check(plc.regs(H_MAILBOX, [CODE_RAPID_RATE] + f32_regs([0.5] + [0] * 11) + [2]) == 0,
              "a whole mailbox write")
        wait_until(lambda: plc.ir(I_RAPIDRATE_PERMILLE)[0] == 500, 10, "rapid rate 500")
        check(sent(sim, "rapid_rate") == [{"cmdName": "rapid_rate", "rate_value": 0.5}],
              "rapid_rate sent: %r (the override was %d)" % (sent(sim, "rapid_rate"), rate))
        check(plc.ir(I_MAILBOX_COUNT)[0] == 2, "mailbox count")
    finally:
        stop(sim, gw, plc)


# ---- items 5 and 6: the owner is a PLC; no motion without a heartbeat ----

def test_owner_is_a_plc_not_a_socket():
    sim, gw = started(CONTRACT + "owner = host\n")
    reader = writer = None
    try:
        reader = Plc(gw)
        reader.ready()
        reader.heartbeat()
        # The same PLC's second connection (reads on one, writes on the
        # other, as Siemens MB_CLIENT blocks do).
        writer = Plc(gw)
        ex = writer.pulse(C_POWER_ON)
        owner = regs_text(reader.ir(I_WRITE_OWNER, 24))
        print("  second connection of the owner's host: %s; IR 66 %r" %
              ("accepted" if ex == 0 else "exception %02x" % ex, owner))
        check(ex == 0, "the owner PLC's second connection refused: %02x" % ex)
        # Yet only the owner's connection feeds the heartbeat: another
        # program on the PLC's host cannot keep it alive.
        check(writer.reg(H_HEARTBEAT, 4242) == EX_NOT_PERMITTED,
              "a second connection fed the heartbeat")
        port = reader.client.socket.getsockname()[1]
        check(owner == "127.0.0.1:%d" % port, "IR 66 reads %r" % owner)
    finally:
        stop(sim, gw, *[p for p in (reader, writer) if p])
    # owner = connection (the default): only the heartbeat's connection
    # writes, and the refusal names its address and port.
    sim, gw = started()
    try:
        reader = Plc(gw)
        reader.ready()
        reader.heartbeat()
        writer = Plc(gw)
        check(writer.coil(C_POWER_ON, 1) == EX_NOT_PERMITTED, "owner = connection: accepted")
        port = reader.client.socket.getsockname()[1]
        check(regs_text(reader.ir(I_WRITE_OWNER, 24)) == "127.0.0.1:%d" % port, "IR 66")
        wait_until(lambda: "not the write owner: 127.0.0.1:%d feeds the heartbeat" % port
                   in gw.output(), 5, "the refusal naming the owner's address and port")
    finally:
        stop(sim, gw, reader, writer)


def test_refused_write_leaves_the_owners_parameters():
    """A write refused for who sent it changes nothing: a client outside
    write_allow, and another connection of the owner's host, each write one
    register of the joint_move block (01); the owner's trigger still sends
    the target it wrote."""
    sim, gw = started(CONTRACT + "[modbus]\nwrite_allow = 127.0.0.1\n")
    owner = intruder = second = None
    try:
        owner = Plc(gw)
        owner.ready()
        owner.heartbeat()
        owner.power_and_enable()
        target = [0, 90, 90, 0, 90, 0]  # where the arm is: nothing moves
        check(owner.regs(H_JOINT_MOVE, f32_regs(target + [20, 100]) + [0]) == 0, "the block")
        intruder = ModbusPlc(gw.modbus_port, source="127.0.0.2")
        second = Plc(gw)
        for who, plc in (("outside write_allow", intruder), ("not the owner", second)):
            ex = plc.reg(H_JOINT_MOVE + 4, 0)
            print("  a client %s writes HR %d: exception %02x" % (who, H_JOINT_MOVE + 4, ex))
            check(ex == EX_NOT_PERMITTED, "%s: exception %02x" % (who, ex))
        ex = owner.pulse(C_JOINT_MOVE)
        r = owner.result("joint_move")
        print("  the owner's trigger after them: exception %02x, %r" % (ex, r))
        check(ex == 0, "the owner's trigger refused %02x: %r" % (ex, r))
        owner.wait_done("joint_move")
        check(sent(sim, "joint_move")[-1]["jointPosition"] == target, "the target sent")
    finally:
        stop(sim, gw, *[p for p in (owner, intruder, second) if p])


def test_stop_never_refused_for_a_full_queue():
    """The gateway's queue full (rapid_rate setpoints behind a robot that
    answers each 1.5 s late): a setpoint more is refused busy (06), the
    PLC's stop_program is not, and reaches the robot ahead of the queue."""
    sim, gw = started(sim_args=("--log-commands", "--reply-delay", "rapid_rate:1500"))
    plc = None
    try:
        plc = Plc(gw)
        plc.ready()
        plc.heartbeat()
        codes = [plc.reg(H_RAPID_RATE, 500 + i) for i in range(70)]
        print("  70 rapid_rate setpoints: %d accepted, %d busy (06)"
              % (codes.count(0), codes.count(6)))
        check(6 in codes, "the queue never filled: %s" % codes)
        ex = plc.pulse(C_STOP)
        r = plc.result("stop_program")
        print("  stop_program with the queue full: exception %02x, %r" % (ex, r))
        check(ex == 0 and r["state"] in (PENDING, DONE), "stop_program refused %02x: %r" % (ex, r))
        wait_until(lambda: sent(sim, "stop_program"), 5, "stop_program at the robot")
        names = [c["cmdName"] for c in sim_commands(sim) if c["cmdName"] in
                 ("rapid_rate", "stop_program")]
        check(names.index("stop_program") <= 2, "stop_program behind %d rapid_rates"
              % names.index("stop_program"))
    finally:
        stop(sim, gw, *[p for p in (plc,) if p])


def status_json(port):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        conn.request("GET", "/status.json")
        return json.loads(conn.getresponse().read())
    finally:
        conn.close()


def test_no_motion_before_the_heartbeat():
    http_port = free_port()
    sim, gw = started(CONTRACT + "[http]\nenabled = true\nport = %d\n" % http_port)
    plc = Plc(gw)
    try:
        plc.ready()
        wait_until(lambda: port_open(http_port), 10, "the HTTP port")
        check(plc.ir(I_PLC_HEARTBEAT_STATE)[0] == 0, "IR 5603 before any heartbeat")
        check(status_json(http_port)["policy"]["plc_heartbeat_state"] == "never",
              "/status.json's plc_heartbeat_state before any heartbeat")
        # Power, enable, outputs and setpoints are not held back.
        plc.power_and_enable()
        check(plc.coil(C_CABINET_DO_1, 1) == 0, "an output refused without a heartbeat")
        check(plc.reg(100, 900) == 0, "rapid_rate refused without a heartbeat")
        # A program start and a move are.
        name = b"track/recipe.jks".ljust(64, b"\0")
        check(plc.regs(H_PROGRAM_NAME, list(struct.unpack(">32H", name))) == 0 and
              plc.pulse(106) == 0, "load_program")
        wait_until(lambda: plc.ir(4144)[0] == DONE, 10, "load_program done")
        ex = plc.pulse(C_PLAY)
        r = plc.result("play_program")
        print("  play_program with the PLC silent: exception %02x, %r" % (ex, r["msg"]))
        check(ex == EX_NOT_PERMITTED and r["msg"] == "heartbeat not started",
              "play_program without a heartbeat: %02x %r" % (ex, r))
        check(plc.regs(H_JOINT_MOVE, f32_regs([0, 90, 90, 0, 90, 0, 30, 100]) + [0]) == 0,
              "joint_move parameters")
        check(plc.pulse(C_JOINT_MOVE) == EX_NOT_PERMITTED and
              plc.result("joint_move")["msg"] == "heartbeat not started", "joint_move")
        mailbox = [30] + f32_regs([0, 90, 90, 0, 90, 0, 30, 100, 0, 0, 0, 0]) + [1]
        check(plc.regs(H_MAILBOX, mailbox) == EX_NOT_PERMITTED, "mailbox joint_move")
        check(not sent(sim, "play_program") and not sent(sim, "joint_move"),
              "started without a heartbeat")
        # The heartbeat changes: IR 5603 running, and the start goes.
        plc.heartbeat()
        check(plc.ir(I_PLC_HEARTBEAT_STATE)[0] == 1, "IR 5603 after a heartbeat")
        check(status_json(http_port)["policy"]["plc_heartbeat_state"] == "running",
              "/status.json after a heartbeat")
        check(plc.pulse(C_PLAY) == 0, "play_program after the heartbeat")
        wait_until(lambda: len(sent(sim, "play_program")) == 1, 10, "play_program at the robot")
    finally:
        stop(sim, gw, plc)


# ---- item 7: reasons, the JSON mailbox, read-back inputs ----

def test_json_refusal_clears_the_reply_and_reasons_fit():
    sim, gw = started("[commands]\nmotion = false\n")
    plc = Plc(gw)
    try:
        plc.ready()

        def json_request(text):
            regs = list(struct.unpack(">120H", text.encode().ljust(240, b"\0")))
            check(plc.regs(H_JSON_REQUEST, regs) == 0, "JSON request")
            return plc.pulse(C_JSON_TRIGGER)

        check(json_request('{"cmdName":"get_version"}') == 0, "get_version")
        wait_until(lambda: plc.ir(I_JSON_STATE)[0] == DONE, 10, "the JSON reply")
        check("version" in regs_text(plc.ir(I_JSON_REPLY, 64)), "no reply shown")
        check(json_request('{"cmdName":"shutdown"}') == EX_NOT_PERMITTED, "shutdown accepted")
        reply = regs_text(plc.ir(I_JSON_REPLY, 64))
        msg = regs_text(plc.ir(I_JSON_STATE + 3, 20))
        print("  JSON reply after a refusal: %r; reason %r" % (reply, msg))
        check(reply == "" and plc.u32(I_JSON_LENGTH) == 0, "the old reply kept: %r" % reply)
        check(msg == "shutdown off: [commands] allow_shutdown", "reason %r" % msg)
        check(plc.ir(I_JSON_COUNT)[0] == 2, "JSON count")
        # A motion trigger with motion off: its reason whole.
        check(plc.pulse(C_JOINT_MOVE) == EX_NOT_PERMITTED, "joint_move with motion off")
        check(plc.result("joint_move")["msg"] == "motion off: [commands] motion",
              "joint_move reason %r" % plc.result("joint_move")["msg"])
    finally:
        stop(sim, gw, plc)


def test_output_coils_read_back_where_the_map_says():
    rows = {(r["table"], int(r["address"])): r for r in map_rows()}
    # The addresses used above are the map's.
    for (table, address), name in ((("coil", C_JOINT_MOVE), "cmd_joint_move"),
                                   (("coil", C_MOVEL), "cmd_moveL"),
                                   (("holding_register", H_MOVEL), "movel_pose_1"),
                                   (("input_register", I_PLC_HEARTBEAT_STATE),
                                    "plc_heartbeat_state"),
                                   (("input_register", I_MAILBOX_COUNT), "mailbox_count"),
                                   (("input_register", I_JSON_COUNT), "json_count"),
                                   (("input_register", RESULT["joint_move"] + 23),
                                    "result_joint_move_count")):
        check(rows[(table, address)]["name"] == name, "%s %d is %s, not %s" %
              (table, address, rows[(table, address)]["name"], name))
    check(("holding_register", 357) not in rows, "HR 357 has a row")
    sim, gw = started("")
    plc = Plc(gw)
    try:
        plc.ready()
        for coil, expect_di in ((C_CABINET_DO_1, 513), (C_TOOL_DO_0, 72)):
            desc = rows[("coil", coil)]["description"]
            check("reads back at discrete input %d" % expect_di in desc,
                  "coil %d: %r names no read-back input" % (coil, desc))
            check(plc.coil(coil, 1) == 0, "coil %d" % coil)
            wait_until(lambda: plc.di(expect_di)[0] == 1, 10,
                       "coil %d's output at discrete input %d" % (coil, expect_di))
            check(plc.coil(coil, 0) == 0, "coil %d" % coil)
            wait_until(lambda: plc.di(expect_di)[0] == 0, 10,
                       "coil %d's output off at discrete input %d" % (coil, expect_di))
    finally:
        stop(sim, gw, plc)


if __name__ == "__main__":
    run([test_trigger_left_at_1_retransmitted_or_refused_never_sent_twice,
         test_movel_block_in_one_fc16_and_no_move_to_a_target_never_written,
         test_mailbox_sequence_alone_is_refused,
         test_owner_is_a_plc_not_a_socket,
         test_refused_write_leaves_the_owners_parameters,
         test_stop_never_refused_for_a_full_queue,
         test_no_motion_before_the_heartbeat,
         test_json_refusal_clears_the_reply_and_reasons_fit,
         test_output_coils_read_back_where_the_map_says])
