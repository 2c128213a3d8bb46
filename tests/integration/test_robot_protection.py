#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The robot's own protection: jakasim honours set_network_exception_handle
(manual 4.75) as a controller would. A program or a move still running when
the command connection that set the handler is lost is kept, paused or
stopped per motType, timeLimit ms after the loss was seen, and one log line
says what, why and after how long.

A plain Python client plays the gateway: it sets the handler, starts a
program, then loses its connection three ways: closed (FIN), reset (RST,
SO_LINGER 0), or silent (no link check for --link-check-ms, then timeLimit).
Our own status connection timestamps every document, so the reaction time
is measured where the gateway and a PLC would see it (interp_state, paused,
inpos). Then the two layers together: the real jakagw in front of jakasim,
a program running, jakagw held by SIGSTOP (both links silent as the robot
sees them): the robot pauses the program by itself, and the PLC reads it
paused once the gateway is back.

Bounds: the action never comes before timeLimit (silence: link check plus
timeLimit) after the loss, less 30 ms of timer rounding; it comes within
that plus SLACK_S, generous for a loaded 2-core machine under ASan. The
figures measured are printed."""
import json
import re
import signal
import socket
import struct
import subprocess
import sys
import time

from harness import (JAKAGW, Gateway, ModbusPlc, Sim, check, log_lines, map_rows, run,
                     sim_commands, wait_until)

LINK_CHECK_MS = 300   # jakasim --link-check-ms in the client tests
TIME_LIMIT_MS = 500   # the handler's timeLimit in the client tests
SLACK_S = 1.0
EARLY_S = 0.03        # timer rounding: libuv's clock is the loop's
PROGRAM = "protect.jks"
IDLE, PAUSED, RUNNING = 0, 2, 3
KEEP, PAUSE, STOP = 0, 1, 2
MOTION_NAMES = {KEEP: "keep", PAUSE: "pause", STOP: "stop"}
EXPECTED_STATE = {KEEP: RUNNING, PAUSE: PAUSED, STOP: IDLE}
ACTION_LINE = re.compile(r"jakasim: network exception on command connection (\d+): (.*); "
                         r"waited (\d+) ms \(timeLimit (\d+) ms\); motType (\d) \((\w+)\): "
                         r"(.*)$")
WHY = {"fin": "closed by the client (FIN)", "rst": "reset by the client (RST)",
       "silent": "silent for "}


class Client:
    """A command-port client, as the gateway is one."""

    def __init__(self, sim):
        self.sock = socket.create_connection(("127.0.0.1", sim.command_port), timeout=5)
        self.buf = b""
        self.sent_at = None

    def call(self, cmd, **params):
        self.sent_at = time.monotonic()
        self.sock.sendall(json.dumps(dict(cmdName=cmd, **params)).encode())
        decoder = json.JSONDecoder()
        deadline = time.monotonic() + 5
        while True:
            try:
                obj, end = decoder.raw_decode(self.buf.decode())
                self.buf = self.buf[end:]
                return obj
            except ValueError:
                pass
            check(time.monotonic() < deadline, "no reply to %s" % cmd)
            chunk = self.sock.recv(65536)
            check(chunk, "command port closed during %s" % cmd)
            self.buf += chunk

    def ok(self, cmd, **params):
        reply = self.call(cmd, **params)
        check(reply.get("errorCode") == "0", "%s refused: %r" % (cmd, reply))
        return reply

    def lose(self, kind):
        """Loses the connection: 'fin' closes it, 'rst' resets it, 'silent'
        stops sending. Returns when the loss began."""
        if kind == "silent":
            return self.sent_at
        if kind == "rst":
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        at = time.monotonic()
        self.sock.close()
        return at

    def close(self):
        self.sock.close()


class StatusStream:
    """Our own status-port connection: every document, with the time it
    arrived."""

    def __init__(self, sim):
        self.sock = socket.create_connection(("127.0.0.1", sim.status_port), timeout=5)
        self.buf = b""
        self.last = None

    def _take(self, block, timeout=0.2):
        """Reads what has arrived; returns the documents it completed."""
        self.sock.settimeout(timeout if block else 0)
        try:
            chunk = self.sock.recv(1 << 20)
            check(chunk, "status port closed")
            self.buf += chunk
        except (socket.timeout, BlockingIOError):
            pass
        now = time.monotonic()
        docs = []
        while True:
            start = self.buf.find(b'{"len": ')
            if start < 0:
                break
            comma = self.buf.find(b",", start)
            if comma < 0:
                break
            n = int(self.buf[start + 8:comma])
            if len(self.buf) < start + n:
                break
            docs.append((now, json.loads(self.buf[start:start + n])))
            self.buf = self.buf[start + n:]
        if docs:
            self.last = docs[-1]
        return docs

    def latest(self):
        """The newest document, after reading everything queued."""
        while self._take(False):
            pass
        if not self.last:
            self.wait(lambda d: True, 5, "a status document")
        return self.last[1]

    def wait(self, pred, timeout, what):
        """The first document from now on that satisfies 'pred': (arrival
        time, document)."""
        if self.last:
            self.latest()  # from now on: what is queued is older
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for at, doc in self._take(True):
                if pred(doc):
                    return at, doc
        raise AssertionError("timed out after %.1f s waiting for %s" % (timeout, what))

    def all_for(self, seconds):
        """Every document of the next 'seconds'."""
        self.latest()
        out = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            out += [d for _, d in self._take(True, 0.05)]
        return out

    def close(self):
        self.sock.close()


def action_lines(sim):
    """The handler's log lines so far, parsed."""
    out = []
    for line in log_lines(sim, "network exception on command connection"):
        m = ACTION_LINE.search(line)
        check(m, "a handler line that does not parse: %r" % line)
        out.append(dict(id=int(m.group(1)), why=m.group(2), waited=int(m.group(3)),
                        limit=int(m.group(4)), motion=int(m.group(5)), name=m.group(6),
                        done=m.group(7)))
    return out


def start_program(c, status):
    """The robot on, a program loaded and running."""
    c.ok("stop_program") if c.call("get_program_state")["programState"] != "idle" else None
    c.ok("power_on")
    c.ok("enable_robot")
    c.ok("load_program", programName=PROGRAM)
    c.ok("play_program")
    status.wait(lambda d: d["interp_state"] == RUNNING, 5, "the program running")


def joints_still(docs):
    """The arm did not move over these documents."""
    return all(d["joint_actual_position"] == docs[0]["joint_actual_position"] for d in docs)


def expect_one_action(sim, before, kind, motion, what, timeout):
    """Waits for the one handler line this loss makes; checks it; returns
    it and when it was seen."""
    wait_until(lambda: len(action_lines(sim)) > before, timeout, "the handler's log line")
    seen = time.monotonic()
    lines = action_lines(sim)
    check(len(lines) == before + 1, "more than one handler line: %r" % lines[before:])
    line = lines[-1]
    check(line["why"].startswith(WHY[kind]), "why: %r" % line["why"])
    check(line["limit"] == TIME_LIMIT_MS and line["motion"] == motion and
          line["name"] == MOTION_NAMES[motion], "handler in the line: %r" % line)
    check(line["done"] == what, "the line says %r, expected %r" % (line["done"], what))
    check(TIME_LIMIT_MS - 30 <= line["waited"] <= TIME_LIMIT_MS + 1000 * SLACK_S,
          "waited %d ms for a timeLimit of %d ms" % (line["waited"], TIME_LIMIT_MS))
    return line, seen


# ---- a plain client as the gateway ----

def test_program_kept_paused_stopped_on_each_loss():
    sim = Sim("--link-check-ms", str(LINK_CHECK_MS))
    status = StatusStream(sim)
    figures = []
    try:
        for kind in ("fin", "rst", "silent"):
            for motion in (PAUSE, STOP, KEEP):
                c = Client(sim)
                start_program(c, status)
                c.ok("set_network_exception_handle", timeLimit=TIME_LIMIT_MS, motType=motion)
                before = len(action_lines(sim))
                bound = TIME_LIMIT_MS / 1000
                if kind == "silent":
                    # Link checks as the gateway sends them, on an idle
                    # link, keep it: over three times the silence bound.
                    end = time.monotonic() + 3 * (LINK_CHECK_MS + TIME_LIMIT_MS) / 1000
                    while time.monotonic() < end:
                        time.sleep(LINK_CHECK_MS / 1000)
                        c.ok("get_robot_state")
                    check(status.latest()["interp_state"] == RUNNING and
                          len(action_lines(sim)) == before,
                          "the handler acted while link checks arrived")
                    bound += LINK_CHECK_MS / 1000
                lost = c.lose(kind)
                what = ("%s the program %s" % ({PAUSE: "paused", STOP: "stopped"}[motion], PROGRAM)
                        if motion != KEEP else "kept the program %s running" % PROGRAM)
                if motion == KEEP:
                    line, seen = expect_one_action(sim, before, kind, motion, what,
                                                   bound + SLACK_S)
                    delay = seen - lost
                    docs = status.all_for(0.3)
                    check(all(d["interp_state"] == RUNNING for d in docs) and
                          not joints_still(docs), "the program did not keep running")
                else:
                    at, doc = status.wait(lambda d: d["interp_state"] != RUNNING,
                                          bound + SLACK_S, "the program to leave running")
                    delay = at - lost
                    check(doc["interp_state"] == EXPECTED_STATE[motion],
                          "interp_state %d after the loss" % doc["interp_state"])
                    check(doc["paused"] is (motion == PAUSE), "paused %r" % doc["paused"])
                    check(doc["inpos"] is True, "inpos after the program halted")
                    check(joints_still(status.all_for(0.2)), "the arm moves after the halt")
                    expect_one_action(sim, before, kind, motion, what, 2)
                check(bound - EARLY_S <= delay <= bound + SLACK_S,
                      "%s, motType %d: %.3f s after the loss, bound %.3f s"
                      % (kind, motion, delay, bound))
                figures.append("%s/%s %.0f ms" % (kind, MOTION_NAMES[motion], 1000 * delay))
                if kind == "silent":
                    # The robot dropped the connection it declared lost.
                    c.sock.settimeout(2)
                    try:
                        gone = c.sock.recv(1) == b""
                    except ConnectionResetError:
                        gone = True
                    check(gone, "the silent connection is still open")
                    c.close()
                if motion == PAUSE:
                    # A new connection does not undo a pause.
                    c2 = Client(sim)
                    c2.ok("get_robot_state")
                    docs = status.all_for(0.5)
                    check(all(d["interp_state"] == PAUSED for d in docs),
                          "a new connection changed the paused state")
                    check(c2.call("get_program_state")["programState"] == "paused",
                          "get_program_state after the pause")
                    c2.ok("resume_program")
                    status.wait(lambda d: d["interp_state"] == RUNNING, 3,
                                "the program to resume")
                    c2.ok("stop_program")
                    c2.close()
        print("  reaction, timeLimit %d ms (silence: + link check %d ms): %s"
              % (TIME_LIMIT_MS, LINK_CHECK_MS, ", ".join(figures)), flush=True)
    finally:
        status.close()
        sim.stop()


def test_handler_belongs_to_its_connection():
    """A client that never set a handler loses nothing by leaving; the one
    that set it does."""
    sim = Sim()
    status = StatusStream(sim)
    try:
        keeper = Client(sim)
        keeper.ok("set_network_exception_handle", timeLimit=TIME_LIMIT_MS, motType=PAUSE)
        other = Client(sim)
        start_program(other, status)
        other.lose("fin")
        docs = status.all_for(TIME_LIMIT_MS / 1000 + SLACK_S)
        check(all(d["interp_state"] == RUNNING for d in docs),
              "a connection without a handler paused the program")
        check(action_lines(sim) == [], "a handler line for a connection without one")
        lost = keeper.lose("rst")
        at, doc = status.wait(lambda d: d["interp_state"] != RUNNING,
                              TIME_LIMIT_MS / 1000 + SLACK_S, "the pause")
        check(doc["interp_state"] == PAUSED, "interp_state %d" % doc["interp_state"])
        check(at - lost >= TIME_LIMIT_MS / 1000 - EARLY_S, "paused before timeLimit")
        # Without --link-check-ms, silence is not a loss.
        quiet = Client(sim)
        quiet.ok("set_network_exception_handle", timeLimit=100, motType=STOP)
        quiet.ok("resume_program")
        docs = status.all_for(1.0)
        check(all(d["interp_state"] == RUNNING for d in docs[3:]),
              "a silent connection counted as lost without --link-check-ms")
        quiet.ok("stop_program")
        quiet.close()
    finally:
        status.close()
        sim.stop()


def test_waiting_for_a_reply_is_not_silence():
    """A client waiting for a slow reply sends no link check (the gateway
    never checks a link with a command in flight): its silence counts from
    the reply on."""
    delay_ms = 3 * (LINK_CHECK_MS + TIME_LIMIT_MS)
    sim = Sim("--link-check-ms", str(LINK_CHECK_MS), "--reply-delay-ms", str(delay_ms),
              "--delay-command", "get_version")
    status = StatusStream(sim)
    try:
        c = Client(sim)
        start_program(c, status)
        c.ok("set_network_exception_handle", timeLimit=TIME_LIMIT_MS, motType=PAUSE)
        c.ok("get_version")
        replied = time.monotonic()
        waited = replied - c.sent_at
        check(waited >= delay_ms / 1000 - EARLY_S, "the reply came after %.3f s" % waited)
        check(status.latest()["interp_state"] == RUNNING and action_lines(sim) == [],
              "paused while the client waited %.1f s for a reply" % waited)
        at, doc = status.wait(lambda d: d["interp_state"] != RUNNING,
                              (LINK_CHECK_MS + TIME_LIMIT_MS) / 1000 + SLACK_S,
                              "the pause after the reply")
        check(doc["interp_state"] == PAUSED, "interp_state %d" % doc["interp_state"])
        check(at - replied >= (LINK_CHECK_MS + TIME_LIMIT_MS) / 1000 - EARLY_S,
              "paused %.3f s after the reply" % (at - replied))
        c.close()
    finally:
        status.close()
        sim.stop()


def test_move_paused_and_resumed_or_stopped():
    """A move (joint_move) is paused where it is and goes on to its target
    after resume_program; stopped, it ends where it is."""
    sim = Sim()
    status = StatusStream(sim)
    target = [60, 90, 90, 0, 90, 0]
    try:
        c = Client(sim)
        c.ok("power_on")
        c.ok("enable_robot")
        c.ok("set_network_exception_handle", timeLimit=TIME_LIMIT_MS, motType=PAUSE)
        c.ok("joint_move", relFlag=0, jointPosition=target, speed=15, accel=100)
        status.wait(lambda d: not d["inpos"], 3, "the move to start")
        lost = c.lose("fin")
        at, doc = status.wait(lambda d: d["interp_state"] == PAUSED,
                              TIME_LIMIT_MS / 1000 + SLACK_S, "the move paused")
        check(at - lost >= TIME_LIMIT_MS / 1000 - EARLY_S, "paused before timeLimit")
        check(doc["paused"] is True and doc["inpos"] is False, "a paused move's status")
        docs = status.all_for(0.3)
        check(joints_still(docs), "the arm moved while paused")
        check(abs(docs[-1]["joint_actual_position"][0] - 60) > 5, "the move had ended")
        line = action_lines(sim)[-1]
        check(line["done"] == "paused the move", "line %r" % line)
        c = Client(sim)
        c.ok("resume_program")
        status.wait(lambda d: d["inpos"] and d["interp_state"] == IDLE, 10,
                    "the move to end at its target")
        pos = status.latest()["joint_actual_position"]
        check(all(abs(p - t) < 1e-6 for p, t in zip(pos, target)), "arrived at %r" % pos)
        # Stopped: the arm stays short of the target.
        c.ok("set_network_exception_handle", timeLimit=TIME_LIMIT_MS, motType=STOP)
        c.ok("joint_move", relFlag=0, jointPosition=[0, 90, 90, 0, 90, 0], speed=15, accel=100)
        status.wait(lambda d: not d["inpos"], 3, "the move to start")
        c.lose("rst")
        at, doc = status.wait(lambda d: d["inpos"], TIME_LIMIT_MS / 1000 + SLACK_S,
                              "the move stopped")
        check(doc["interp_state"] == IDLE and doc["paused"] is False, "a stopped move's status")
        check(abs(doc["joint_actual_position"][0]) > 5, "the move was not stopped short")
        check(joints_still(status.all_for(0.3)), "the arm moved after the stop")
        check(action_lines(sim)[-1]["done"] == "stopped the move", "the stop line")
    finally:
        status.close()
        sim.stop()


# ---- the two layers: the real jakagw in front of jakasim ----

ADDR = {}
for _row in map_rows():
    ADDR.setdefault((_row["table"], _row["name"]), int(_row["address"]))


def gateway_checks_links():
    """Whether this jakagw has [robot] link_check_ms (it checks an idle
    command link). Without it the command link is silent while idle, so
    the PLC keeps it busy instead, as a PLC writing outputs does."""
    keys = subprocess.run([JAKAGW, "--print-config-keys"], check=True, capture_output=True,
                          text=True).stdout
    return any(line.split("\t")[:2] == ["robot", "link_check_ms"] for line in keys.splitlines())


def test_silent_gateway_pauses_the_program():
    """jakagw held by SIGSTOP while a program runs: its link checks stop,
    its sockets stay open (no FIN, no RST), as when a cable is pulled. With
    the defaults (link_check_ms 1000, robot_time_limit_ms 1000, robot_action
    pause) the robot pauses the program by itself within 2 s plus slack."""
    link_check_ms, time_limit_ms = 1000, 1000
    checks = gateway_checks_links()
    sim = Sim("--auto-run", "--log-commands", "--link-check-ms", str(link_check_ms))
    status = StatusStream(sim)
    gw = plc = None
    try:
        gw = Gateway(sim, "")
        plc = ModbusPlc(gw.modbus_port)
        interp = ADDR[("input_register", "interp_state")]
        paused_di = ADDR[("discrete_input", "paused")]
        handle = ADDR[("input_register", "robot_handle")]
        wait_until(lambda: plc.ir(handle)[0] == 2, 10, "the robot to accept the handler")
        do_coil = next(int(r["address"]) for r in map_rows()
                       if r["table"] == "coil" and r["source"] == "cmd:set_digital_output.value")
        value = 0

        def keep_busy(seconds):
            nonlocal value
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                if not checks:
                    value ^= 1
                    check(plc.coil(do_coil, value) == 0, "a DO write refused")
                time.sleep(0.25)

        # The link lives: no action over twice the silence bound.
        keep_busy(2 * (link_check_ms + time_limit_ms) / 1000)
        check(status.latest()["interp_state"] == RUNNING and action_lines(sim) == [],
              "the robot acted while the gateway was alive:\n" + sim.output()[-2000:])
        check(plc.ir(interp)[0] == RUNNING, "the PLC does not read the program running")
        print("  the command link kept alive by %s" %
              ("jakagw's link checks" if checks else "the PLC's DO writes"), flush=True)
        plc.close()
        plc = None
        held = time.monotonic()
        gw.proc.send_signal(signal.SIGSTOP)
        at, doc = status.wait(lambda d: d["interp_state"] != RUNNING,
                              (link_check_ms + time_limit_ms) / 1000 + SLACK_S,
                              "the robot to pause the program by itself")
        delay = at - held
        check(doc["interp_state"] == PAUSED and doc["paused"] is True,
              "interp_state %d after the gateway went silent" % doc["interp_state"])
        lines = action_lines(sim)
        check(len(lines) == 1 and lines[0]["why"].startswith("silent for ") and
              lines[0]["done"] == "paused the program demo.jks", "handler lines %r" % lines)
        check(time_limit_ms / 1000 - EARLY_S <= delay <=
              (link_check_ms + time_limit_ms) / 1000 + SLACK_S,
              "paused %.3f s after the gateway stopped" % delay)
        check(not any(c["cmdName"] in ("pause_program", "stop_program")
                      for c in sim_commands(sim)), "the gateway sent the pause, not the robot")
        print("  silent gateway: paused by the robot %.0f ms after SIGSTOP (%s)"
              % (1000 * delay, lines[0]["why"]), flush=True)
        gw.proc.send_signal(signal.SIGCONT)
        # The gateway reconnects and sets the handler again: the program
        # stays paused, and the PLC reads it so.
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: len(sim_commands(sim, "set_network_exception_handle")) >= 2, 15,
                   "the gateway to reconnect and set the handler again")
        wait_until(lambda: plc.ir(interp)[0] == PAUSED and plc.di(paused_di)[0] == 1, 5,
                   "the PLC to read the program paused")
        check(status.latest()["interp_state"] == PAUSED, "a new connection undid the pause")
        plc.close()
        plc = None
    finally:
        if plc:
            plc.close()
        status.close()
        try:
            if gw:
                if gw.alive():
                    gw.proc.send_signal(signal.SIGCONT)
                gw.stop()
        finally:
            sim.stop()


if __name__ == "__main__":
    tests = [test_program_kept_paused_stopped_on_each_loss, test_handler_belongs_to_its_connection,
             test_waiting_for_a_reply_is_not_silence, test_move_paused_and_resumed_or_stopped,
             test_silent_gateway_pauses_the_program]
    if sys.argv[1:]:
        tests = [t for t in tests if t.__name__ in sys.argv[1:]]  # named tests only
    run(tests)
