# SPDX-License-Identifier: MIT
"""Shared helpers for jakagw's integration tests.

Tests start the real jakasim and the real jakagw on free loopback ports,
talk to them with real clients (pymodbus, raw sockets, mbpoll), and stop
exactly the processes they started, by pid. A sanitizer report in any log
fails the test.
"""
import atexit
import contextlib
import csv
import io
import json
import os
import random
import shlex
import shutil
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

# The runner prefix: a command line put before every binary of the build
# the tests start. make test ARCH=armhf sets it to "qemu-arm -L SYSROOT", so
# the ARM binaries run under qemu-user and nothing else in the tests
# changes. qemu-user runs the guest inside its own process: a pid the tests
# hold (signals, /proc/PID/fd, VmRSS) is the gateway's. JAKAGW and JAKASIM
# then name small scripts that exec the prefix and the binary (exec keeps
# the pid), so that every way a test starts them takes the prefix; so does
# the reference slave of test_abuse (REF_SLAVE).
RUNNER = shlex.split(os.environ.get("JAKAGW_RUNNER", ""))


def _through_runner(path):
    if not RUNNER or not os.path.exists(path):
        return path
    wrap_dir = _through_runner.dir
    if wrap_dir is None:
        wrap_dir = _through_runner.dir = tempfile.mkdtemp(prefix="jakagw-runner-")
        atexit.register(shutil.rmtree, wrap_dir, True)
    wrapper = os.path.join(wrap_dir, os.path.basename(path))
    with open(wrapper, "w") as f:
        f.write("#!/bin/sh\nexec %s %s \"$@\"\n" % (" ".join(shlex.quote(a) for a in RUNNER),
                                                  shlex.quote(path)))
    os.chmod(wrapper, 0o755)
    return wrapper


_through_runner.dir = None
if RUNNER:
    JAKAGW = _through_runner(JAKAGW)
    JAKASIM = _through_runner(JAKASIM)
    if not os.environ.get("REF_SLAVE"):
        os.environ["REF_SLAVE"] = _through_runner(os.path.abspath(os.path.join(BIN, "bench",
                                                                               "ref_slave")))
SANITIZER_MARKS = ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:")


class TestFailure(Exception):
    pass


def check(cond, what):
    if not cond:
        raise TestFailure(what)


_ports_given = set()


# The ARM runs go side by side in CI (.ci/run), each its own process tree:
# each takes its ports from a range of its own, below the kernel's
# ephemeral range (32768 and up), so that neither run nor an outgoing
# connection can be handed a port the other was just given.
_PORT_RANGES = {"armhf": (20000, 26000), "arm64": (26000, 32000)}


def free_port():
    """A loopback port nobody listens on, never one this process was given
    before: two calls before either port is bound could otherwise return
    the same port (the kernel hands a closed ephemeral port out again), and
    a gateway given it for two listeners refuses to start."""
    span = _PORT_RANGES.get(os.environ.get("JAKAGW_ARCH", ""))
    for _ in range(100):
        with socket.socket() as s:
            try:
                s.bind(("127.0.0.1", random.randrange(*span) if span else 0))
            except OSError:
                continue  # in use: another one
            port = s.getsockname()[1]
        if port not in _ports_given:
            _ports_given.add(port)
            return port
    raise TestFailure("no free loopback port in 100 tries")


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


# ---- the robot's side and the gateway's process, for the policy and
# link-fault suites ----

class SimAt(Sim):
    """jakasim on given ports: a controller restarted where the gateway
    already looks for it."""

    def __init__(self, status_port, command_port, *args):
        self.status_port = status_port
        self.command_port = command_port
        Process.__init__(self, "jakasim", [JAKASIM, "--status-port", str(status_port),
                                           "--command-port", str(command_port)] + list(args))
        wait_until(lambda: not self.alive() or (port_open(status_port)
                                                and port_open(command_port)),
                   30, "jakasim to listen")
        check(self.alive(), "jakasim exited at start:\n" + self.output())


SIM_COMMAND_MARK = "jakasim: command "
SIM_DROP_MARK = "jakasim: dropping every connection"


def sim_events(sim):
    """What jakasim --log-commands saw, in order: ("command", cmdName,
    request text, reply text or None) per command, ("drop",) each time
    --drop-every-ms closed every connection."""
    out = []
    decoder = json.JSONDecoder()
    for line in sim.output().splitlines():
        if SIM_DROP_MARK in line:
            out.append(("drop",))
            continue
        at = line.find(SIM_COMMAND_MARK)
        if at < 0:
            continue
        rest = line[at + len(SIM_COMMAND_MARK):]
        if not rest.startswith("{"):
            continue  # "command client connected"
        try:
            request, end = decoder.raw_decode(rest)
            name = request.get("cmdName") if isinstance(request, dict) else None
        except ValueError:
            out.append(("command", None, rest, None))
            continue
        reply = rest[end:]
        out.append(("command", name, rest[:end],
                    reply[4:] if reply.startswith(" -> ") else None))
    return out


def sim_commands(sim, name=None):
    """The requests jakasim received (those named 'name'), as parsed JSON."""
    return [json.loads(e[2]) for e in sim_events(sim)
            if e[0] == "command" and (name is None or e[1] == name)]


def is_housekeeping(name):
    """What the gateway sends by itself: the handler and information fetches."""
    return name == "set_network_exception_handle" or (name or "").startswith("get_")


def open_fds(pid):
    """How many descriptors process 'pid' holds open."""
    return len(os.listdir("/proc/%d/fd" % pid))


def rss_kb(pid):
    """Resident memory of process 'pid', in KiB."""
    with open("/proc/%d/status" % pid) as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    raise TestFailure("no VmRSS for pid %d" % pid)


def log_lines(process, text):
    """The lines of a process's log that contain 'text'."""
    return [l for l in process.output().splitlines() if text in l]


class ModbusPlc:
    """A PLC through pymodbus: reads return values, writes return 0 or the
    exception code (pymodbus never retries: nothing is sent twice)."""

    def __init__(self, port, source=None, timeout=5):
        from pymodbus.client import ModbusTcpClient
        self.client = ModbusTcpClient("127.0.0.1", port=port, timeout=timeout, retries=0,
                                      source_address=(source, 0) if source else None)
        check(self.client.connect(), "Modbus connect to port %d" % port)

    def close(self):
        self.client.close()

    @staticmethod
    def _outcome(rr, what):
        from pymodbus.pdu import ExceptionResponse
        if isinstance(rr, ExceptionResponse):
            return rr.exception_code
        check(not rr.isError(), "%s: %s" % (what, rr))
        return 0

    def coil(self, address, value):
        return self._outcome(self.client.write_coil(address, bool(value), slave=1),
                             "write coil %d" % address)

    def reg(self, address, value):
        return self._outcome(self.client.write_register(address, value, slave=1),
                             "write register %d" % address)

    def regs(self, address, values):
        return self._outcome(self.client.write_registers(address, values, slave=1),
                             "write registers %d+%d" % (address, len(values)))

    def pulse(self, address):
        """A trigger coil as a PLC pulses it: 0, then 1 (0 -> 1 acts)."""
        check(self.coil(address, 0) == 0, "re-arming coil %d" % address)
        return self.coil(address, 1)

    def coils(self, address, values):
        return self._outcome(self.client.write_coils(address, [bool(v) for v in values],
                                                     slave=1), "write coils %d" % address)

    def ir(self, address, count=1):
        """Input registers, in reads of at most 125."""
        out = []
        while count > 0:
            n = min(count, 125)
            rr = self.client.read_input_registers(address, n, slave=1)
            check(not rr.isError(), "read input registers %d+%d: %s" % (address, n, rr))
            out += rr.registers
            address, count = address + n, count - n
        return out

    def hr(self, address, count=1):
        rr = self.client.read_holding_registers(address, count, slave=1)
        check(not rr.isError(), "read holding registers %d: %s" % (address, rr))
        return rr.registers

    def u32(self, address):
        hi, lo = self.ir(address, 2)
        return hi << 16 | lo

    def text(self, address, count):
        raw = b"".join(struct.pack(">H", r) for r in self.ir(address, count))
        return raw.rstrip(b"\0").decode("utf-8", "replace")

    def di(self, address, count=1):
        rr = self.client.read_discrete_inputs(address, count, slave=1)
        check(not rr.isError(), "read discrete inputs %d: %s" % (address, rr))
        return [int(b) for b in rr.bits[:count]]

    def read_coils(self, address, count=1):
        rr = self.client.read_coils(address, count, slave=1)
        check(not rr.isError(), "read coils %d: %s" % (address, rr))
        return [int(b) for b in rr.bits[:count]]


def text_registers(text, count):
    """'text' as NUL-padded registers, two characters each."""
    data = text.encode().ljust(2 * count, b"\0")
    return list(struct.unpack(">%dH" % count, data[:2 * count]))
