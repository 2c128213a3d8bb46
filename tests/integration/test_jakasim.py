#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""jakasim behaves like a controller: the wire format of its status port,
the command port's replies, refusals and quirks, and status that follows
commands."""
import json
import signal
import socket
import time

from harness import DATA, Sim, check, run, wait_until


class Robot:
    """A command-port client that splits replies like the gateway must."""

    def __init__(self, sim):
        self.sim = sim
        self.sock = socket.create_connection(("127.0.0.1", sim.command_port), timeout=5)
        self.buf = b""

    def replies(self, n, timeout=5):
        decoder = json.JSONDecoder()
        out = []
        deadline = time.monotonic() + timeout
        while len(out) < n:
            text = self.buf.decode()
            try:
                obj, end = decoder.raw_decode(text)
                out.append(obj)
                self.buf = text[end:].encode()
                continue
            except ValueError:
                pass
            check(time.monotonic() < deadline, "no reply")
            self.sock.settimeout(max(0.01, deadline - time.monotonic()))
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                continue
            check(chunk, "command port closed")
            self.buf += chunk
        return out

    def call(self, cmd, **params):
        self.sock.sendall(json.dumps(dict(cmdName=cmd, **params)).encode())
        return self.replies(1)[0]

    def close(self):
        self.sock.close()


def status(sim):
    return json.loads(sim.read_document())


class Documents:
    """The status stream, document after document, from one connection."""

    def __init__(self, sim):
        self.sock = socket.create_connection(("127.0.0.1", sim.status_port), timeout=5)
        self.buf = ""
        self.decoder = json.JSONDecoder()

    def drain(self):
        """Drops what has arrived: the next document comes after now."""
        self.sock.setblocking(False)
        try:
            while self.sock.recv(65536):
                pass
        except BlockingIOError:
            pass
        self.sock.setblocking(True)
        self.buf = ""
        self.next()  # may have been cut by the drain: whole from the next on

    def next(self):
        while True:
            start = self.buf.find('{"len"')
            if start >= 0:
                try:
                    doc, end = self.decoder.raw_decode(self.buf[start:])
                    self.buf = self.buf[start + end:]
                    return doc
                except ValueError:
                    pass
            chunk = self.sock.recv(65536)
            check(chunk, "status port closed")
            self.buf += chunk.decode()

    def close(self):
        self.sock.close()


def test_moves_as_the_manual_says():
    """A move takes time at its speed, shows a few documents after its
    reply, is not stopped by pause_program and is by stop_program (4.23
    (b)), an emergency or a protective stop; moveL goes along a straight
    line at its speed in mm/s with actual_position the forward kinematics
    of the joints; moves block (4.7, 4.8)."""
    sim = Sim("--period-ms", "20")
    r, docs = Robot(sim), Documents(sim)
    try:
        r.call("power_on")
        r.call("enable_robot")
        docs.drain()
        check(r.call("joint_move", relFlag=0, jointPosition=[40, 90, 90, 0, 90, 0], speed=40,
                     accel=100)["errorCode"] == "0", "joint_move")
        shown = 0
        while True:
            d = docs.next()
            if not d["inpos"]:
                break
            check(d["joint_actual_position"][0] == 0, "moved while in position")
            shown += 1
        print("  the move showed in the %d-th document after its reply" % (shown + 1))
        check(3 <= shown <= 8, "the move showed after %d documents, not 3" % shown)
        # 40 deg/s: 0.8 deg a 20 ms document.
        a, b = docs.next()["joint_actual_position"][0], docs.next()["joint_actual_position"][0]
        check(abs(b - a - 0.8) < 1e-6, "joint 1 went %.3f deg in a document" % (b - a))
        reply = r.call("pause_program")
        check(reply["errorCode"] == "2" and reply["errorMsg"] == "no program is running",
              "pause_program on a move: %r" % reply)
        a, b = docs.next()["joint_actual_position"][0], docs.next()["joint_actual_position"][0]
        check(b > a, "pause_program stopped the move")
        r.call("stop_program")
        docs.next()
        held = docs.next()
        check(held["inpos"] and held["joint_actual_position"] == docs.next()["joint_actual_position"],
              "stop_program did not stop the move")
        check(held["joint_actual_position"][0] < 40, "the move ended anyway")
        # moveL: +40 mm in z at 100 mm/s, on the line.
        start = held["actual_position"]
        check(r.call("moveL", relFlag=1, cartPosition=[0, 0, 40, 0, 0, 0], speed=100, accel=100,
                     tol=0.5)["errorCode"] == "0", "moveL")
        moving = 0
        while True:
            d = docs.next()
            tcp = d["actual_position"]
            check(all(abs(tcp[i] - start[i]) < 0.01 for i in (0, 1, 3, 4, 5)),
                  "moveL left the line: %r from %r" % (tcp, start))
            fk = r.call("kine_forward", jointPosition=d["joint_actual_position"])["cartPosition"]
            check(all(abs(x - y) < 1e-6 for x, y in zip(fk, tcp)),
                  "actual_position is not the joints' forward kinematics")
            if d["inpos"] and tcp[2] > start[2]:
                break
            moving += not d["inpos"]
        check(abs(tcp[2] - start[2] - 40) < 1e-3, "moveL ended at z %+.4f" % (tcp[2] - start[2]))
        check(19 <= moving <= 21, "moveL took %d documents, 0.4 s is 20" % moving)
        # Moves block: the second starts once the first has ended.
        first, second = [5, 90, 90, 0, 90, 0], [5, 95, 90, 0, 90, 0]
        for target in (first, second):
            check(r.call("joint_move", relFlag=0, jointPosition=target, speed=40,
                         accel=100)["errorCode"] == "0", "joint_move")
        seen = []
        while not seen or seen[-1] != second:
            seen.append([round(v, 6) for v in docs.next()["joint_actual_position"]])
        check(first in seen, "the second move did not wait for the first")
        # A protective stop, then an emergency stop, end a move where it is.
        for sig, what in ((signal.SIGUSR2, "protective stop"), (signal.SIGRTMIN, "e-stop")):
            check(r.call("joint_move", relFlag=1, jointPosition=[20, 0, 0, 0, 0, 0], speed=40,
                         accel=100)["errorCode"] == "0", "%s: joint_move" % what)
            while docs.next()["inpos"]:
                pass
            sim.proc.send_signal(sig)
            docs.next()
            docs.next()
            a, b = docs.next(), docs.next()
            check(a["joint_actual_position"] == b["joint_actual_position"] and b["inpos"],
                  "%s: the arm still moves" % what)
            if sig == signal.SIGRTMIN:
                check(not b["enabled"], "an emergency stop leaves the robot enabled")
            sim.proc.send_signal(sig)  # cleared, released
            key = "protective_stop" if sig == signal.SIGUSR2 else "emergency_stop"
            while docs.next()[key]:
                pass
        r.close()
        docs.close()
    finally:
        sim.stop()


def test_wire_format_is_python_json_with_exact_len():
    for args in (["--profile", "full"], ["--profile", "manual"], ["--profile", "zu5s"],
                 ["--test-pattern"], ["--replay", DATA + "/status-zu5s-1.5.14.json"]):
        sim = Sim(*args)
        try:
            raw = sim.read_document()
            doc = json.loads(raw)
            check(list(doc)[0] == "len" and doc["len"] == len(raw),
                  "%s: len %s for %d bytes" % (args, doc.get("len"), len(raw)))
            check(json.dumps(doc).encode() == raw,
                  "%s: not serialised as Python's json.dumps would" % args)
        finally:
            sim.stop()
    sim = Sim("--profile", "zu5s")
    try:
        doc = status(sim)
        check(len(doc["din"]) == 135 and len(doc["ain"]) == 64 and "extio" not in doc,
              "zu5s profile shape")
        check(len(doc["monitor_data"][5][0]) == 11, "zu5s joint monitor rows")
    finally:
        sim.stop()


def test_commands_follow_the_state_machine():
    sim = Sim()
    r = Robot(sim)
    try:
        reply = r.call("enable_robot")
        check(reply["errorCode"] == "2" and reply["errorMsg"], "enable while off: %r" % reply)
        reply = r.call("power_on")
        check(reply == {"errorCode": "0", "errorMsg": "", "cmdName": "power_on",
                        "power status": "True"}, "power_on reply %r" % reply)
        reply = r.call("enable_robot")
        check(reply["errorCode"] == "0" and reply["enabled status"] == "True", repr(reply))
        check(r.call("play_program")["errorCode"] == "2", "play with no program")
        check(r.call("load_program", programName="track/test.jks")["errorCode"] == "0", "load")
        check(r.call("get_loaded_program")["programName"] == "track/test.jks", "loaded name")
        check(r.call("play_program")["errorCode"] == "0", "play")
        wait_until(lambda: status(sim)["interp_state"] == 3, 3, "program running")
        a = status(sim)["joint_actual_position"]
        wait_until(lambda: status(sim)["joint_actual_position"] != a, 2,
                   "joints to move while the program runs")
        check(r.call("pause_program")["errorCode"] == "0", "pause")
        wait_until(lambda: status(sim)["paused"] is True, 3, "paused in status")
        check(r.call("get_program_state")["programState"] == "paused", "program state")
        check(r.call("resume_program")["errorCode"] == "0", "resume")
        reply = r.call("stop_program")
        check(reply["cmdName"] == "pause_program", "the manual's stop_program quirk: %r" % reply)
        wait_until(lambda: status(sim)["interp_state"] == 0, 3, "program stopped")
        check(r.call("set_digital_output", type=0, index=5, value=1)["errorCode"] == "0", "DO")
        check(r.call("rapid_rate", rate_value=0.25)["errorCode"] == "0", "rapid rate")
        check(r.call("rapid_rate", rate_value=1.5)["errorCode"] == "2", "rapid rate > 1")
        check(r.call("set_tool_id", tool_id=2)["errorCode"] == "0", "tool id")
        doc = status(sim)
        check(doc["dout"][5] == 1 and doc["rapidrate"] == 0.25 and doc["current_tool_id"] == 2,
              "status does not follow the commands")
        target = [10, 80, 100, 5, 85, 15]
        check(r.call("joint_move", relFlag=0, jointPosition=target, speed=200,
                     accel=100)["errorCode"] == "0", "joint_move")
        wait_until(lambda: not status(sim)["inpos"], 2, "moving")
        wait_until(lambda: status(sim)["inpos"], 5, "in position")
        pos = status(sim)["joint_actual_position"]
        check(all(abs(p - t) < 1e-6 for p, t in zip(pos, target)), "arrived at %r" % pos)
        fk = r.call("kine_forward", jointPosition=target)["cartPosition"]
        check(all(abs(a - b) < 1e-6 for a, b in zip(fk, status(sim)["actual_position"])),
              "forward kinematics disagrees with the status")
        ik = r.call("kine_inverse", jointPosition=[0, 90, 90, 0, 90, 0], cartPosition=fk)
        check(ik["errorCode"] == "0", "kine_inverse %r" % ik)
        fk2 = r.call("kine_forward", jointPosition=ik["jointPosition"])["cartPosition"]
        check(all(abs(a - b) < 1e-3 for a, b in zip(fk, fk2)), "IK round trip")
        reply = r.call("servo_j", relFlag=1, jointPosition=[0.1, 0, 0, 0, 0, 0], stepNum=1)
        check(reply["errorCode"] == "-1" and "excuted" in reply["errorMsg"], repr(reply))
        reply = r.call("no_such_command")
        check(reply["errorCode"] == "1", "unknown command %r" % reply)
        reply = r.call("emergency_stop_status")
        check("cmdName" not in reply and reply["errorCode"] == "1", repr(reply))
        check(r.call("power_off")["errorCode"] == "0", "power off")
        doc = status(sim)
        check(doc["powered_on"] == 0 and doc["enabled"] is False and doc["task_state"] == 1,
              "power off not in status")
        # Two commands in one write: two replies, in order.
        r.sock.sendall(b'{"cmdName": "get_version"}{"cmdName": "get_robot_state"}')
        a, b = r.replies(2)
        check(a["cmdName"] == "get_version" and b["power"] == "powered_off", "%r %r" % (a, b))
        r.close()
    finally:
        sim.stop()


def test_command_faults():
    sim = Sim("--fail-command", "power_on", "--ignore-command", "get_version")
    r = Robot(sim)
    try:
        reply = r.call("power_on")
        check(reply["errorCode"] == "2" and reply["errorMsg"] == "call power_on failed",
              repr(reply))
        r.sock.sendall(b'{"cmdName": "get_version"}{"cmdName": "get_robot_state"}')
        only = r.replies(1)
        check(only[0]["cmdName"] == "get_robot_state", "ignored command answered: %r" % only)
        r.close()
    finally:
        sim.stop()


def test_brakes_and_answers_in_order():
    """--stop-time-ms: a move ramps up and down, a stop from full speed
    takes the stopping time (the arm moves on, slowing, after the reply),
    a paused program slows down to rest and can be resumed; --reply-delay
    holds one command's reply, and the replies behind it keep their order
    (a controller answers in order)."""
    sim = Sim("--period-ms", "20", "--move-lag", "0", "--stop-time-ms", "400",
              "--reply-delay", "rapid_rate:300")
    r, docs = Robot(sim), Documents(sim)
    try:
        r.call("power_on")
        r.call("enable_robot")
        docs.drain()
        check(r.call("joint_move", relFlag=1, jointPosition=[90, 0, 0, 0, 0, 0], speed=60,
                     accel=100)["errorCode"] == "0", "joint_move")
        steps, last = [], docs.next()["joint_actual_position"][0]
        while len(steps) < 30:
            now = docs.next()["joint_actual_position"][0]
            steps.append(now - last)
            last = now
        # 60 deg/s reached in 0.4 s: 1.2 deg a document from the 20th on.
        check(steps[1] < steps[5] < steps[12] < 1.2 - 1e-6, "no ramp up: %r" % steps[:14])
        check(abs(steps[-1] - 1.2) < 1e-6, "not at full speed: %r" % steps[-5:])
        check(r.call("stop_program")["errorCode"] == "0", "stop_program")
        at_stop, moving, prev = last, 0, None
        while True:
            d = docs.next()
            pos = d["joint_actual_position"][0]
            if pos == prev:
                break
            moving += 1
            prev = pos
        print("  stopped %.2f deg and %d documents after stop_program" % (pos - at_stop, moving))
        check(17 <= moving <= 23, "the stop took %d documents, 0.4 s is 20" % moving)
        check(10 <= pos - at_stop <= 14, "braked %.2f deg, 60 deg/s over 0.4 s is 12" %
              (pos - at_stop))
        check(d["inpos"] and pos < last + 30, "the move went on after its stop")
        # A move accepted while the arm brakes runs once it is at rest.
        check(r.call("joint_move", relFlag=1, jointPosition=[40, 0, 0, 0, 0, 0], speed=60,
                     accel=100)["errorCode"] == "0", "joint_move")
        for _ in range(15):
            docs.next()
        check(r.call("stop_program")["errorCode"] == "0", "stop_program")
        braking_at = docs.next()["joint_actual_position"][0]
        check(r.call("joint_move", relFlag=0, jointPosition=[-10, 90, 90, 0, 90, 0], speed=60,
                     accel=100)["errorCode"] == "0", "joint_move while braking")
        check(docs.next()["joint_actual_position"][0] > braking_at, "not braking")
        # 90 documents of simulated time at most; slow under valgrind.
        wait_until(lambda: abs(docs.next()["joint_actual_position"][0] + 10) < 1e-6, 60,
                   "the move accepted while braking to run")
        # A program paused slows down to rest, and stays resumable.
        check(r.call("load_program", programName="demo.jks")["errorCode"] == "0", "load")
        check(r.call("play_program")["errorCode"] == "0", "play")
        wait_until(lambda: docs.next()["joint_actual_position"] != docs.next()
                   ["joint_actual_position"], 60, "the program moving the arm")
        check(r.call("pause_program")["errorCode"] == "0", "pause")
        a, b = docs.next()["joint_actual_position"], docs.next()["joint_actual_position"]
        check(a != b, "a paused program stood still at once")
        wait_until(lambda: docs.next()["joint_actual_position"] == docs.next()
                   ["joint_actual_position"], 60, "the paused program to come to rest")
        check(r.call("get_program_state")["programState"] == "paused", "not paused")
        check(r.call("resume_program")["errorCode"] == "0", "resume")
        # A held reply: what follows it waits behind it.
        r.sock.sendall(b'{"cmdName": "rapid_rate", "rate_value": 0.5}'
                       b'{"cmdName": "get_version"}')
        a, b = r.replies(2)
        check(a["cmdName"] == "rapid_rate" and b["cmdName"] == "get_version",
              "replies out of order: %r %r" % (a, b))
        r.close()
        docs.close()
    finally:
        sim.stop()


if __name__ == "__main__":
    run([test_wire_format_is_python_json_with_exact_len, test_commands_follow_the_state_machine,
         test_command_faults, test_moves_as_the_manual_says, test_brakes_and_answers_in_order])
