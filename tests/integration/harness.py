"""Shared helpers for jakagw's integration tests.

Tests start the real jakasim and the real jakagw on free loopback ports,
talk to them with real clients (pymodbus, raw sockets, mbpoll), and stop
exactly the processes they started, by pid. A sanitizer report in any log
fails the test.
"""
import contextlib
import csv
import io
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time

BIN = os.environ.get("JAKAGW_BIN_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "build"))
JAKAGW = os.path.abspath(os.path.join(BIN, "jakagw"))
JAKASIM = os.path.abspath(os.path.join(BIN, "jakasim"))
DATA = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "data"))
SANITIZER_MARKS = ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:")


class TestFailure(Exception):
    pass


def check(cond, what):
    if not cond:
        raise TestFailure(what)


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_until(cond, timeout, what, interval=0.02):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(interval)
    raise TestFailure("timed out after %.1f s waiting for %s" % (timeout, what))


VALGRIND = ["valgrind", "-q", "--error-exitcode=99", "--leak-check=full",
            "--errors-for-leak-kinds=definite"]


class Process:
    """A child process with its output in a temporary log file. With
    JAKAGW_VALGRIND=1 it runs under valgrind, and a valgrind error fails
    the test through the exit code."""

    def __init__(self, name, argv, env=None):
        if os.environ.get("JAKAGW_VALGRIND") == "1":
            argv = VALGRIND + argv
        self.name = name
        self.log = tempfile.NamedTemporaryFile(prefix=name + "-", suffix=".log", delete=False)
        self.proc = subprocess.Popen(argv, stdout=self.log, stderr=subprocess.STDOUT,
                                     env=dict(os.environ, **(env or {})))

    def output(self):
        with open(self.log.name, "r", errors="replace") as f:
            return f.read()

    def alive(self):
        return self.proc.poll() is None

    def stop(self, expect_code=0):
        """SIGTERM, wait up to 10 s; a hang or a bad exit fails the test."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise TestFailure("%s did not stop within 10 s of SIGTERM" % self.name)
        out = self.output()
        os.unlink(self.log.name)
        for mark in SANITIZER_MARKS:
            check(mark not in out, "%s: sanitizer report:\n%s" % (self.name, out[-4000:]))
        if expect_code is not None:
            check(self.proc.returncode == expect_code,
                  "%s exited %s, expected %s; log:\n%s" % (self.name, self.proc.returncode,
                                                            expect_code, out[-3000:]))
        return out


class Sim(Process):
    def __init__(self, *args):
        self.status_port = free_port()
        self.command_port = free_port()
        super().__init__("jakasim", [JAKASIM, "--status-port", str(self.status_port),
                                     "--command-port", str(self.command_port)] + list(args))
        wait_until(lambda: port_open(self.status_port) and port_open(self.command_port), 30,
                   "jakasim to listen")

    def read_document(self, timeout=5):
        """One whole document as the simulator sends it, from our own connection."""
        with socket.create_connection(("127.0.0.1", self.status_port), timeout=timeout) as s:
            buf = b""
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                buf += s.recv(65536)
                start = buf.find(b'{"len": ')
                if start < 0:
                    continue
                end_len = buf.find(b",", start)
                if end_len < 0:
                    continue
                n = int(buf[start + 8:end_len])
                if len(buf) >= start + n:
                    return buf[start:start + n]
        raise TestFailure("no status document from jakasim")


class Gateway(Process):
    def __init__(self, sim, config=None, extra=(), env=None):
        self.modbus_port = free_port()
        self.conf = tempfile.NamedTemporaryFile("w", prefix="jakagw-", suffix=".conf", delete=False)
        self.conf.write(config or "")
        self.conf.close()
        argv = [JAKAGW, "-c", self.conf.name, "--robot-host", "127.0.0.1",
                "--status-port", str(sim.status_port if sim else free_port()),
                "--command-port", str(sim.command_port if sim else free_port()),
                "--modbus-bind", "127.0.0.1", "--modbus-port", str(self.modbus_port)] + list(extra)
        super().__init__("jakagw", argv, env)
        wait_until(lambda: port_open(self.modbus_port) or not self.alive(), 30,
                   "jakagw to listen")
        check(self.alive(), "jakagw exited at start:\n" + self.output())

    def stop(self, expect_code=0):
        try:
            return super().stop(expect_code)
        finally:
            os.unlink(self.conf.name)


@contextlib.contextmanager
def running(sim_args=(), config=""):
    """A jakasim and a jakagw in front of it; both stopped, and checked for
    a clean exit, whatever the test does."""
    sim = Sim(*sim_args)
    gw = None
    try:
        gw = Gateway(sim, config)
        yield sim, gw
    finally:
        try:
            if gw:
                gw.stop()
        finally:
            sim.stop()


def port_open(port):
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.2):
            return True
    except OSError:
        return False


def print_map(fmt="csv"):
    out = subprocess.run([JAKAGW, "--print-map", fmt], check=True, capture_output=True)
    return out.stdout


def map_rows():
    return list(csv.DictReader(io.StringIO(print_map("csv").decode())))


# ---- a minimal Modbus TCP client on raw sockets, for byte-exact tests ----

def mbap(tid, pdu, unit=1):
    return struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu


def recv_exact(sock, n):
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise TestFailure("connection closed after %d of %d bytes" % (len(data), n))
        data += chunk
    return data


def recv_adu(sock):
    """One Modbus TCP reply: (transaction id, unit, pdu)."""
    head = recv_exact(sock, 7)
    tid, proto, length, unit = struct.unpack(">HHHB", head)
    check(proto == 0, "reply protocol id %d" % proto)
    return tid, unit, recv_exact(sock, length - 1)


def raw_client(port, timeout=5):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def read_input_registers(sock, address, count, tid=1):
    sock.sendall(mbap(tid, struct.pack(">BHH", 4, address, count)))
    rtid, _, pdu = recv_adu(sock)
    check(rtid == tid, "transaction id %d, expected %d" % (rtid, tid))
    check(pdu[0] == 4, "exception reply %s" % pdu.hex())
    return list(struct.unpack(">%dH" % count, pdu[2:]))


def read_bits(sock, function, address, count, tid=1):
    sock.sendall(mbap(tid, struct.pack(">BHH", function, address, count)))
    rtid, _, pdu = recv_adu(sock)
    check(rtid == tid and pdu[0] == function, "bad reply %s" % pdu.hex())
    return [(pdu[2 + i // 8] >> (i % 8)) & 1 for i in range(count)]


def run(tests):
    """Runs test functions; prints one line each and a closing count."""
    passed = failed = 0
    for t in tests:
        start = time.monotonic()
        try:
            t()
            passed += 1
            print("PASS %s (%.1f s)" % (t.__name__, time.monotonic() - start), flush=True)
        except Exception as e:  # a failing test must not stop the others
            failed += 1
            print("FAIL %s: %s: %s" % (t.__name__, type(e).__name__, e), flush=True)
    print("%d passed, %d failed" % (passed, failed))
    sys.exit(1 if failed else 0)
