#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""jakasim behaves like a controller: the wire format of its status port,
the command port's replies, refusals and quirks, and status that follows
commands."""
import json
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


if __name__ == "__main__":
    run([test_wire_format_is_python_json_with_exact_len, test_commands_follow_the_state_machine,
         test_command_faults])
