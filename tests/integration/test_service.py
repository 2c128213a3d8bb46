#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""jakagw as a service: SIGHUP reloads the configuration (a bad file keeps
the running one), SIGTERM answers the requests that have arrived before it
stops, and a socket passed by systemd (socket activation) is served."""
import os
import re
import shutil
import signal
import socket
import struct

from pymodbus.client import ModbusTcpClient

from harness import (JAKAGW, Gateway, Process, Sim, TestFailure, check, free_port, mbap,
                     port_open, raw_client, read_input_registers, recv_adu, run, running,
                     wait_until)


def write_conf(gw, text):
    # Written whole and renamed over, as an editor or a deployment tool would.
    tmp = gw.conf.name + ".new"
    with open(tmp, "w") as f:
        f.write(text)
    os.rename(tmp, gw.conf.name)


def reload(gw, expect):
    """SIGHUP, then wait for the line that ends the reload."""
    before = gw.output().count("received SIGHUP")
    gw.proc.send_signal(signal.SIGHUP)
    wait_until(lambda: gw.output().count("received SIGHUP") > before
               and expect in gw.output().split("received SIGHUP")[-1], 10,
               "the reload to log %r" % expect)
    return gw.output().split("received SIGHUP")[-1]


def closed_within(sock, seconds):
    sock.settimeout(seconds)
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True
    except socket.timeout:
        return False


def test_sighup_applies_live_keys_and_names_the_others():
    conf = "[modbus]\nidle_timeout_ms = 60000\n"
    with running((), conf) as (sim, gw):
        with raw_client(gw.modbus_port) as s:
            check(read_input_registers(s, 4, 1) == [0], "word order before the reload")
        write_conf(gw, "[modbus]\nidle_timeout_ms = 300\nword_order = low_first\n"
                       "[robot]\nmax_document_bytes = 131072\n[log]\nlevel = notice\n")
        tail = reload(gw, "need a restart")
        check("2 changes applied, 2 need a restart" in tail, "summary: %s" % tail)
        check("reload: [modbus] idle_timeout_ms: 60000 -> 300" in tail, tail)
        check("reload: [log] level: info -> notice" in tail, tail)
        check("reload: [modbus] word_order: low_first needs a restart; high_first stays "
              "in force until then" in tail, tail)
        check("reload: [robot] max_document_bytes: 131072 needs a restart" in tail, tail)
        # The new idle timeout is in force; the word order is not.
        with raw_client(gw.modbus_port) as s:
            check(read_input_registers(s, 4, 1) == [0], "word order changed without a restart")
            check(closed_within(s, 3), "an idle client was not closed after 300 ms")
        # The flags still override the file: the port given with --modbus-port stays.
        write_conf(gw, "[modbus]\nport = 1\nidle_timeout_ms = 300\n")
        tail = reload(gw, "changes applied")
        check("[modbus] port" not in tail, "a flag lost to the file on reload: %s" % tail)


def test_sighup_with_a_bad_file_keeps_the_running_configuration():
    conf = "[modbus]\nidle_timeout_ms = 400\n"
    with running((), conf) as (sim, gw):
        bad = [
            ("[modbus]\nidle_timeout_ms = 60000\nbogus = 1\n", ":3: [modbus] bogus: unknown key"),
            ("[modbus]\nidle_timeout_ms = 60000\nframe_timeout_ms = 1\n",
             ":3: [modbus] frame_timeout_ms: 1 is out of range 50..60000"),
            ("[robot]\nreconnect_min_ms = 9000\nreconnect_max_ms = 1000\n",
             "reconnect_min_ms: 9000 exceeds reconnect_max_ms 1000"),
        ]
        for text, why in bad:
            write_conf(gw, text)
            tail = reload(gw, "reload refused")
            check("reload refused, the running configuration stays in force: "
                  "configuration error: " in tail and why in tail, "%r: %s" % (text, tail))
            check("reload: [" not in tail, "a key changed from a bad file: %s" % tail)
        os.unlink(gw.conf.name)
        tail = reload(gw, "reload refused")
        check("cannot open" in tail, tail)
        check(gw.alive(), "jakagw stopped on a bad reload")
        # Still serving, with the idle timeout of the first file (400 ms).
        with raw_client(gw.modbus_port) as s:
            check(read_input_registers(s, 0, 1) == [0x4A4B], "magic")
            check(closed_within(s, 3), "the running idle timeout was lost")
        write_conf(gw, conf)  # for Gateway.stop(), which removes it


def stopped(pid):
    with open("/proc/%d/stat" % pid) as f:
        return f.read().rsplit(")", 1)[1].split()[0] == "T"


def test_sigterm_answers_requests_that_have_arrived():
    """While the gateway is held (SIGSTOP), client a pipelines 4000 reads,
    then writes the power_on coil and the heartbeat; b sends a read, and c
    half a request; then SIGTERM, SIGCONT. libuv reads at most 32 buffers
    (16.6 KB here) per client per loop iteration and handles signals after
    the other events of the iteration, so the stop begins with most of a's
    48 KB still in the kernel (even when the signal lands an iteration
    late): the stop must read and answer it.
    Every whole request is answered, in order: the reads with data, the
    writes with exception 06, not acted on. Then every connection is closed,
    and nothing but queries ever reaches the robot."""
    sim = Sim("--log-commands")
    gw = None
    try:
        gw = Gateway(sim)
        wait_until(lambda: "command link: connected" in gw.output(), 10, "the command link")
        a, b, half, idle = (raw_client(gw.modbus_port) for _ in range(4))
        check(read_input_registers(a, 0, 1, tid=1) == [0x4A4B], "first read")
        n = 4000
        gw.proc.send_signal(signal.SIGSTOP)
        try:
            wait_until(lambda: stopped(gw.proc.pid), 10, "jakagw to stop (SIGSTOP)")
            a.sendall(b"".join(mbap(tid, struct.pack(">BHH", 4, 0, 1))
                               for tid in range(1, n + 1))
                      + mbap(n + 1, struct.pack(">BHH", 5, 100, 0xFF00))    # power_on
                      + mbap(n + 2, struct.pack(">BHH", 6, 0, 1234)))       # heartbeat
            b.sendall(mbap(7, struct.pack(">BHH", 2, 0, 3)))
            half.sendall(mbap(9, struct.pack(">BHH", 4, 0, 1))[:9])
            gw.proc.send_signal(signal.SIGTERM)
        finally:
            gw.proc.send_signal(signal.SIGCONT)
        for tid in range(1, n + 1):
            try:
                rtid, _, pdu = recv_adu(a)
            except TestFailure as e:
                raise TestFailure("a: no answer to request %d of %d: %s" % (tid, n, e))
            check(rtid == tid and pdu == bytes([4, 2, 0x4A, 0x4B]),
                  "a: %d %s, expected %d" % (rtid, pdu.hex(), tid))
        for tid, function in ((n + 1, 5), (n + 2, 6)):
            rtid, _, pdu = recv_adu(a)
            check(rtid == tid and pdu == bytes([function | 0x80, 6]),
                  "a: a write while stopping: %d %s, expected exception 06" % (rtid, pdu.hex()))
        rtid, _, pdu = recv_adu(b)
        check(rtid == 7 and pdu[:2] == bytes([2, 1]), "b: %d %s" % (rtid, pdu.hex()))
        for name, s in (("a", a), ("b", b), ("half", half), ("idle", idle)):
            check(closed_within(s, 10), "%s: not closed on stop" % name)
            s.close()
        gw.proc.wait(timeout=10)
        check(not port_open(gw.modbus_port), "still accepting after the stop")
        out = gw.stop()
        gw = None
        check("received Terminated: stopping" in out and "(no command is sent)" in out, out)
        check("write refused: the gateway is stopping (exception 06)" in out, out)
        sim_log = sim.stop()
        sim = None
        # Queries, and the robot's own network-exception handler set on
        # connecting: nothing that moves or changes the robot, at stop or before.
        names = re.findall(r'jakasim: command \{"cmdName": ?"(\w+)"', sim_log)
        check(names and all(n.startswith("get_") or n == "set_network_exception_handle"
                            for n in names),
              "the robot received a command that is not a query: %s\n%s" % (names, sim_log))
    finally:
        if gw:
            gw.stop(expect_code=None)
        if sim:
            sim.stop()


def test_socket_activation_serves_the_passed_socket():
    """systemd-socket-activate (from systemd) binds the port and passes the
    listening socket as fd 3, as jakagw.socket does: jakagw serves it and
    binds nothing itself, whatever [modbus] bind and port say."""
    tool = shutil.which("systemd-socket-activate")
    if not tool:
        raise TestFailure("systemd-socket-activate not installed (package systemd)")
    sim = Sim()
    gw = None
    port = free_port()
    try:
        gw = Process("jakagw", [tool, "-l", "127.0.0.1:%d" % port, JAKAGW, "-c", "/dev/null",
                                "--robot-host", "127.0.0.1",
                                "--status-port", str(sim.status_port),
                                "--command-port", str(sim.command_port),
                                "--modbus-bind", "127.0.0.1", "--modbus-port", "1"])
        # The socket listens before jakagw runs: the first connection starts it.
        wait_until(lambda: port_open(port), 10, "systemd-socket-activate to listen")
        client = ModbusTcpClient("127.0.0.1", port=port, timeout=5)
        check(client.connect(), "pymodbus cannot connect")
        try:
            rr = client.read_input_registers(0, 1, slave=1)
            check(not rr.isError() and rr.registers == [0x4A4B], "magic: %s" % rr)
            wait_until(lambda: client.read_discrete_inputs(2, 1, slave=1).bits[0], 10,
                       "status_fresh over the passed socket")
        finally:
            client.close()
        out = gw.output()
        check("listening on 127.0.0.1 port %d, the socket passed by systemd" % port in out, out)
        check("cannot listen" not in out, out)
        gw.proc.send_signal(signal.SIGHUP)
        wait_until(lambda: "changes applied" in gw.output(), 10, "the reload")
        out = gw.stop()
        gw = None
        check("stopped" in out, out)
    finally:
        if gw:
            gw.stop(expect_code=None)
        sim.stop()


def test_passed_sockets_that_cannot_be_served_exit_2():
    tool = shutil.which("systemd-socket-activate")
    if not tool:
        raise TestFailure("systemd-socket-activate not installed (package systemd)")
    p1, p2 = free_port(), free_port()
    gw = Process("jakagw", [tool, "-l", "127.0.0.1:%d" % p1, "-l", "127.0.0.1:%d" % p2,
                            JAKAGW, "-c", "/dev/null"])
    try:
        wait_until(lambda: port_open(p1), 10, "systemd-socket-activate to listen")
        gw.proc.wait(timeout=10)
        out = gw.stop(expect_code=2)
        check("systemd passed 2 file descriptors" in out, out)
    finally:
        if gw.alive():
            gw.stop(expect_code=None)


if __name__ == "__main__":
    run([test_sighup_applies_live_keys_and_names_the_others,
         test_sighup_with_a_bad_file_keeps_the_running_configuration,
         test_sigterm_answers_requests_that_have_arrived,
         test_socket_activation_serves_the_passed_socket,
         test_passed_sockets_that_cannot_be_served_exit_2])
