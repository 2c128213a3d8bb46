#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Modbus/TCP Security (mbaps) with real certificates and real clients.

The certificates come from tests/tls/make-pki.sh: the openssl commands of
docs/security.md, run as written, and the test-only ones (no role, an
unknown role, expired, revoked, another CA). The clients are pymodbus's
TLS client, Python's ssl module and `openssl s_client`; the gateway is the
real jakagw in front of the real jakasim.
"""
import multiprocessing
import os
import re
import select
import socket
import ssl
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.dirname(__file__))
from harness import (Gateway, ModbusPlc, Sim, TestFailure, check, free_port, log_lines,  # noqa: E402
                     map_rows, mbap, open_fds, port_open, raw_client, read_input_registers, recv_adu,
                     rss_kb, run, sim_commands, sim_events, wait_until)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
# Under valgrind (make valgrind) a handshake takes 20-50 times longer: the
# deadlines of the gateway and the waits of the tests grow by this factor.
SLOW = 10 if os.environ.get("JAKAGW_VALGRIND") == "1" else 1
PKI = tempfile.mkdtemp(prefix="jakagw-pki-")
subprocess.run([os.path.join(ROOT, "tests", "tls", "make-pki.sh"), PKI], check=True)

# Input registers (docs/register-map.md).
IR_TLS_CLIENTS, IR_HANDSHAKES_RUNNING, IR_HANDSHAKES_OK, IR_FAILED_TOTAL = 90, 91, 92, 94
IR_FAILED = {"no_certificate": 5500, "untrusted": 5502, "expired": 5504, "revoked": 5506,
             "protocol": 5508, "timeout": 5510, "over_limit": 5512}
IR_ROBOT_HANDLE = 64
COIL_CABINET_DO_1 = 200
COIL_JOINT_MOVE = 112
HR_HEARTBEAT = 0


def pki(name):
    return os.path.join(PKI, name)


def tls_config(port, extra=""):
    return """
[tls]
enabled = true
port = %d
certificate = %s
private_key = %s
client_ca = %s
crl = %s
handshake_timeout_ms = %d
max_handshakes = 16

[network_exception]
single_owner = false

[roles]
operator = heartbeat, faults, setpoints, outputs, power, programs, payload
monitor = read
%s""" % (port, pki("gateway.crt"), pki("gateway.key"), pki("ca.crt"), pki("ca.crl"),
           1000 * SLOW, extra)


class Mbaps:
    """A sim and a gateway with the mbaps listener."""

    def __init__(self, extra="", edit=None, env=None):
        self.tls_port = free_port()
        self.sim = Sim("--log-commands")
        config = tls_config(self.tls_port, extra)
        try:
            self.gw = Gateway(self.sim, edit(config) if edit else config, env=env)
            wait_until(lambda: port_open(self.tls_port), 10 * SLOW, "the mbaps port")
        except Exception:
            self.sim.stop(None)
            raise

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        try:
            self.gw.stop()
        finally:
            self.sim.stop()

    def plain(self):
        return ModbusPlc(self.gw.modbus_port)

    def counter(self, address):
        s = raw_client(self.gw.modbus_port)
        try:
            hi, lo = read_input_registers(s, address, 2)
            return hi << 16 | lo
        finally:
            s.close()


def client_context(name, max_version=None):
    ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH, cafile=pki("ca.crt"))
    if name:
        ctx.load_cert_chain(pki(name + ".crt"), pki(name + ".key"))
    if max_version:
        ctx.maximum_version = max_version
    return ctx


def tls_socket(port, name, timeout=5 * SLOW, max_version=None):
    raw = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    raw.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return client_context(name, max_version).wrap_socket(raw, server_hostname="127.0.0.1")


class TlsPlc(ModbusPlc):
    """harness.ModbusPlc over pymodbus's TLS client (MBAP framing, as the
    protocol has it), with the read fix docs/security.md explains."""

    def __init__(self, port, name, timeout=5 * SLOW):
        from pymodbus.client import ModbusTlsClient
        from pymodbus.framer.socket_framer import ModbusSocketFramer

        class TlsClient(ModbusTlsClient):
            def recv(self, size):
                self.socket.settimeout(self.params.timeout)
                data = b""
                try:
                    while len(data) < (size or 1):
                        chunk = self.socket.recv((size or 4096) - len(data))
                        if not chunk:
                            break
                        data += chunk
                except socket.timeout:
                    pass
                return data

        self.client = TlsClient("127.0.0.1", port=port, sslctx=client_context(name),
                                framer=ModbusSocketFramer, timeout=timeout, retries=0)
        check(self.client.connect(), "TLS connect to port %d as %s" % (port, name))


def doc_blocks(kind):
    with open(os.path.join(ROOT, "docs", "security.md")) as f:
        return re.findall(r"^```%s\n(.*?)^```" % kind, f.read(), re.S | re.M)


def test_security_doc_word_for_word():
    """docs/security.md's configuration and PLC, as written: pymodbus reads
    over TLS with the operator certificate, a monitor's write gets 01."""
    (ini,) = doc_blocks("ini")
    (program,) = doc_blocks("python")
    tls_port = free_port()
    ini = ini.replace("/etc/jakagw/tls", PKI).replace("enabled = true",
                                                      "enabled = true\nport = %d" % tls_port)
    sim = Sim()
    try:
        gw = Gateway(sim, ini)
        try:
            wait_until(lambda: port_open(tls_port), 10 * SLOW, "the mbaps port")
            out = subprocess.run([sys.executable, "-c", program.replace("port=802", "port=%d" % tls_port)],
                                 cwd=PKI, capture_output=True, text=True, timeout=60)
            check(out.returncode == 0, "the PLC of docs/security.md failed:\n%s%s"
                  % (out.stdout, out.stderr))
            check("map magic: 0x4a4b" in out.stdout, out.stdout)
            check("monitor writes the heartbeat: Exception Response(134, 6, IllegalFunction)"
                  in out.stdout, out.stdout)
            check(log_lines(gw, 'role "operator": may write heartbeat'), gw.output())
            check(log_lines(gw, 'role "monitor": may write read'), gw.output())
        finally:
            gw.stop()
    finally:
        sim.stop()


def test_roles_decide_writes():
    with Mbaps("intruder_is_not_listed = read\n") as m:
        wait_until(lambda: m.plain().ir(IR_ROBOT_HANDLE)[0] == 2, 10 * SLOW, "the robot's handler")
        op = TlsPlc(m.tls_port, "operator")
        check(op.ir(0)[0] == 0x4A4B, "operator reads")
        check(op.reg(HR_HEARTBEAT, 7) == 0, "operator writes the heartbeat")
        check(op.pulse(COIL_CABINET_DO_1) == 0, "operator sets an output")
        # The pulse wrote 0, then 1: both are sent, one after the other's
        # reply. Counting before the second arrived would count it as sent
        # by a refused write (as it was, under emulation).
        wait_until(lambda: [c for c in sim_commands(m.sim, "set_digital_output")
                            if c.get("value") == 1], 5 * SLOW, "the output command at the robot")
        sent = len(sim_commands(m.sim))
        check(op.coil(COIL_JOINT_MOVE, 1) == 1, "operator has no motion class: 01")
        for name in ("monitor", "norole", "intruder"):
            plc = TlsPlc(m.tls_port, name)
            check(plc.ir(0)[0] == 0x4A4B, "%s reads" % name)
            check(plc.coil(COIL_CABINET_DO_1, 0) == 1, "%s writes an output: 01" % name)
            check(plc.reg(HR_HEARTBEAT, 9) == 1, "%s writes the heartbeat: 01" % name)
            plc.close()
        time.sleep(0.3)
        check(len(sim_commands(m.sim)) == sent, "a refused write sent nothing to the robot")
        check(m.plain().hr(HR_HEARTBEAT) == [7], "refused writes left the image alone")
        out = m.gw.output()
        check(log_lines(m.gw, 'role "intruder"') and "default_rights" in out, out)
        check(log_lines(m.gw, "role (none)"), out)
        # Plain Modbus TCP is as before: every class.
        check(m.plain().pulse(COIL_CABINET_DO_1 + 1) == 0, "plain writes as before")
        check(m.counter(IR_HANDSHAKES_OK) >= 4, "handshakes counted")
        op.close()


def test_plain_client_never_acts_with_a_tls_owners_rights():
    """owner = host, where every connection from the owner's address
    shares its write side: a TLS client feeds the heartbeat and owns the
    writes; a second TLS connection from the same host may write what its
    role allows (not the heartbeat); a plain port-502 client from the same
    host gets exception 01 for the heartbeat, a motion target, a motion
    trigger and an output, and nothing it wrote reaches the robot (the TLS
    connection's next command is the robot's next one)."""
    rate = [int(r["address"]) for r in map_rows()
            if r["table"] == "holding_register" and r["name"] == "rapid_rate"][0]
    owner_ir = [int(r["address"]) for r in map_rows()
                if r["table"] == "input_register" and r["name"] == "write_owner"][0]

    def host_owner(config):
        return config.replace("single_owner = false",
                              "single_owner = true\nowner = host\ntime_limit_ms = 10000")
    with Mbaps("[commands]\nmotion = true\n", edit=host_owner) as m:
        wait_until(lambda: m.plain().ir(IR_ROBOT_HANDLE)[0] == 2, 10 * SLOW, "the robot's handler")
        owner = TlsPlc(m.tls_port, "operator")
        check(owner.reg(HR_HEARTBEAT, 1) == 0, "the TLS owner's heartbeat refused")
        check(owner.text(owner_ir, 24).startswith("127.0.0.1:"), "write_owner reads %r"
              % owner.text(owner_ir, 24))
        other = TlsPlc(m.tls_port, "operator")
        check(other.reg(HR_HEARTBEAT, 2) == 1, "a second TLS connection fed the heartbeat")
        check(other.reg(rate, 501) == 0, "the owner's host over TLS: its setpoint refused")
        wait_until(lambda: sim_commands(m.sim, "rapid_rate"), 5 * SLOW, "rapid_rate at the robot")
        before = len(sim_commands(m.sim))
        plain = m.plain()
        # Joints 10, 90, 90, 0, 90, 0 at 20 deg/s, acceleration 100, absolute.
        target = list(struct.unpack(">16H", struct.pack(">8f", 10, 90, 90, 0, 90, 0, 20, 100))) + [0]
        refused = {"heartbeat (HR 0)": plain.reg(HR_HEARTBEAT, 3),
                   "joint_move's target (HR 300)": plain.regs(300, target),
                   "joint_move (coil 112)": plain.coil(COIL_JOINT_MOVE, 1),
                   "an output (coil 200)": plain.coil(COIL_CABINET_DO_1, 1),
                   "the rapid rate": plain.reg(rate, 502)}
        # The TLS connection's next command: the queue is in order, so
        # anything the plain writes had sent would reach the robot first.
        check(other.reg(rate, 503) == 0, "the TLS connection's setpoint refused")
        wait_until(lambda: [c for c in sim_commands(m.sim, "rapid_rate")
                            if round(1000 * c.get("rate_value", 0)) == 503], 5 * SLOW,
                   "the TLS connection's rapid_rate at the robot")
        after = [c.get("cmdName") for c in sim_commands(m.sim)[before:]]
        print("  plain client on the TLS owner's host: %s; the robot then received %s"
              % (", ".join("%s %02X" % (w, ex) for w, ex in refused.items()), after))
        for what, ex in refused.items():
            check(ex == 1, "the plain client wrote %s: exception %02X, not 01" % (what, ex))
        check(after == ["rapid_rate"], "the robot received %s" % after)
        check(plain.hr(HR_HEARTBEAT) == [1], "the heartbeat reads %s" % plain.hr(HR_HEARTBEAT))
        check(log_lines(m.gw, "not the write owner"), "no log line names the refusal")
        for c in (owner, other, plain):
            c.close()


def no_modbus_answer(port, name, max_version=None):
    """Handshake as 'name' (None: no certificate), then a Modbus request:
    the handshake fails and not one Modbus byte comes back."""
    try:
        s = tls_socket(port, name, timeout=3, max_version=max_version)
    except (ssl.SSLError, OSError):
        return True
    try:
        s.sendall(mbap(1, struct.pack(">BHH", 4, 0, 1)))
        data = s.recv(100)
        return data == b""
    except (ssl.SSLError, OSError):
        return True
    finally:
        s.close()


def test_refused_handshakes_answer_nothing():
    with Mbaps() as m:
        for name, reason in ((None, "no_certificate"), ("stranger", "untrusted"),
                             ("expired", "expired"), ("revoked", "revoked")):
            before = m.counter(IR_FAILED[reason])
            check(no_modbus_answer(m.tls_port, name), "%s: a Modbus byte was answered" % name)
            wait_until(lambda: m.counter(IR_FAILED[reason]) == before + 1, 5 * SLOW,
                       "the %s counter" % reason)
        check(m.counter(IR_HANDSHAKES_OK) == 0, "no handshake succeeded")
        check(m.plain().ir(IR_TLS_CLIENTS)[0] == 0, "no TLS client")


def s_client(port, *args, stdin=b"", timeout=10):
    argv = ["openssl", "s_client", "-connect", "127.0.0.1:%d" % port, "-CAfile", pki("ca.crt"),
            "-cert", pki("operator.crt"), "-key", pki("operator.key")] + list(args)
    return subprocess.run(argv, input=stdin, capture_output=True, timeout=timeout)


def test_old_versions_and_plaintext_refused():
    with Mbaps() as m:
        for flag in ("-tls1", "-tls1_1"):
            before = m.counter(IR_FAILED["protocol"])
            r = s_client(m.tls_port, flag, "-cipher", "DEFAULT@SECLEVEL=0")
            check(r.returncode != 0, "%s accepted:\n%s" % (flag, r.stdout.decode(errors="replace")))
            wait_until(lambda: m.counter(IR_FAILED["protocol"]) == before + 1, 5 * SLOW,
                       "%s counted as a protocol failure" % flag)
        r = s_client(m.tls_port, "-tls1_2", stdin=b"")
        check(b"Protocol  : TLSv1.2" in r.stdout or b"TLSv1.2" in r.stdout,
              "TLS 1.2 works:\n%s" % r.stdout.decode(errors="replace"))
        s = raw_client(m.tls_port, timeout=5)
        s.sendall(mbap(1, struct.pack(">BHH", 4, 0, 1)))
        data = b""
        try:
            while True:
                chunk = s.recv(100)
                if not chunk:
                    break
                data += chunk
        except ConnectionResetError:
            pass
        s.close()
        check(not data.startswith(b"\x00\x01\x00\x00"), "plaintext Modbus answered: %r" % data)


def test_renegotiation_refused():
    with Mbaps() as m:
        # s_client renegotiates on a line "R"; then a Modbus request.
        proc = subprocess.Popen(["openssl", "s_client", "-connect", "127.0.0.1:%d" % m.tls_port,
                                 "-CAfile", pki("ca.crt"), "-cert", pki("operator.crt"),
                                 "-key", pki("operator.key"), "-tls1_2"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT)
        try:
            wait_until(lambda: m.counter(IR_HANDSHAKES_OK) == 1, 10 * SLOW, "the handshake")
            proc.stdin.write(b"R\n")
            proc.stdin.flush()
            out, _ = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        check(b"RENEGOTIATING" in out, out.decode(errors="replace"))
        wait_until(lambda: log_lines(m.gw, "renegotiation refused"), 5 * SLOW,
                   "the gateway to refuse and close")
        wait_until(lambda: m.plain().ir(IR_TLS_CLIENTS)[0] == 0, 5 * SLOW, "the client closed")
        # Counted as the map says: a failed handshake, protocol (IR 5508).
        check(m.counter(IR_FAILED["protocol"]) == 1 and m.counter(IR_FAILED_TOTAL) == 1,
              "renegotiation counted: protocol %d, total %d" % (
                  m.counter(IR_FAILED["protocol"]), m.counter(IR_FAILED_TOTAL)))


def strict_tls_socket(port, name):
    """A TLS client that tells close_notify from a bare end of stream:
    recv() gives b"" only after close_notify; an end of stream without it
    raises SSLEOFError (Python ignores that by default)."""
    raw = socket.create_connection(("127.0.0.1", port), timeout=5 * SLOW)
    ctx = client_context(name)
    ctx.options &= ~ssl.OP_IGNORE_UNEXPECTED_EOF
    return ctx.wrap_socket(raw, server_hostname="127.0.0.1", suppress_ragged_eofs=False)


def ends_with_close_notify(s):
    try:
        while True:
            if s.recv(4096) == b"":
                return True
    except ssl.SSLError as e:
        print("  no close_notify: %s" % e)
        return False
    finally:
        s.close()


def test_gateway_closes_end_with_close_notify():
    """A session the gateway ends (a bad MBAP header, the idle timeout, a
    stop) ends with close_notify, not a bare end of stream."""
    with Mbaps(extra="\n[modbus]\nidle_timeout_ms = %d\n" % (500 * SLOW)) as m:
        s = strict_tls_socket(m.tls_port, "operator")
        check(read_input_registers(s, 0, 1) == [0x4A4B], "a read first")
        s.sendall(b"\x00\x02\x00\x07\x00\x06\x01\x04\x00\x00\x00\x01")  # protocol id 7
        check(ends_with_close_notify(s), "bad MBAP header: close_notify")
        s = strict_tls_socket(m.tls_port, "operator")
        read_input_registers(s, 0, 1)
        check(ends_with_close_notify(s), "idle timeout: close_notify")
        s = strict_tls_socket(m.tls_port, "operator")
        read_input_registers(s, 0, 1)
        m.gw.proc.terminate()
        check(ends_with_close_notify(s), "stop: close_notify")
        m.gw.proc.wait(10 * SLOW)  # a second SIGTERM would end it at once


def test_session_lines_rate_limited():
    """A handshake loop does not fill the log: at most 10 session lines in
    10 s, the rest counted; each says whether the session is new."""
    with Mbaps() as m:
        start = time.monotonic()
        for _ in range(60):
            s = tls_socket(m.tls_port, "operator")
            read_input_registers(s, 0, 1)
            s.close()
        elapsed = time.monotonic() - start
        lines = log_lines(m.gw, 'certificate "CN=plc-operator"')
        print("  60 sessions in %.1f s: %d session lines" % (elapsed, len(lines)))
        check(len(lines) <= 10 * (int(elapsed / 10) + 1), "\n".join(lines))
        check(all("TLSv1.3, new session" in l or "TLSv1.3, session resumed" in l for l in lines),
              "\n".join(lines))
        wait_until(lambda: m.counter(IR_HANDSHAKES_OK) == 60, 5 * SLOW, "60 handshakes counted")
        if elapsed < 10:
            check(len(lines) == 10, "the first 10 sessions logged:\n" + "\n".join(lines))


def poll_loop(read, stop, latencies, failures):
    while not stop.is_set():
        t0 = time.monotonic()
        try:
            read()
            latencies.append(time.monotonic() - t0)
        except Exception:  # noqa: BLE001 - every failure counts
            failures.append(sys.exc_info()[1])
        time.sleep(0.01)


def test_handshake_flood_does_not_starve_pollers():
    """200 handshakes at once and 64 clients stalled mid-handshake, while a
    plain poller and an established TLS poller are answered throughout."""
    # Room for the 64 stalled ones and some of the flood; the rest of the
    # flood is refused at once.
    with Mbaps(edit=lambda c: c.replace("max_handshakes = 16", "max_handshakes = 100")) as m:
        plain = raw_client(m.gw.modbus_port)
        tls = tls_socket(m.tls_port, "operator")
        stop = threading.Event()
        lat = {"plain": [], "tls": []}
        fails = {"plain": [], "tls": []}
        threads = [threading.Thread(target=poll_loop, args=(lambda: read_input_registers(plain, 18, 2), stop, lat["plain"], fails["plain"])),
                   threading.Thread(target=poll_loop, args=(lambda: read_input_registers(tls, 18, 2), stop, lat["tls"], fails["tls"]))]
        for t in threads:
            t.start()
        # 64 that stall: a TCP connection and half a ClientHello.
        stalled = []
        for _ in range(64):
            s = socket.create_connection(("127.0.0.1", m.tls_port))
            s.sendall(b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03")
            stalled.append(s)
        # 200 real handshakes at once.
        results = []

        # Each connects and reads once, as a PLC would: a client gone right
        # after its own Finished leaves its certificate unchecked, its
        # handshake neither completed nor failed at the gateway.
        def shake():
            try:
                s = tls_socket(m.tls_port, "operator", timeout=10)
                try:
                    results.append(read_input_registers(s, 0, 1) == [0x4A4B])
                finally:
                    s.close()
            except (ssl.SSLError, OSError, TestFailure):
                results.append(False)
        flood = [threading.Thread(target=shake) for _ in range(200)]
        for t in flood:
            t.start()
        for t in flood:
            t.join()
        time.sleep(1.5)  # past handshake_timeout_ms for the stalled ones
        closed = 0
        for s in stalled:
            s.settimeout(2)
            try:
                closed += s.recv(10) == b""
            except OSError:
                closed += 1
            s.close()
        stop.set()
        for t in threads:
            t.join()
        tls.close()
        plain.close()
        for kind in ("plain", "tls"):
            q = statistics.quantiles(lat[kind], n=100)
            print("  %s poller: %d reads, %d failures, p50 %.1f ms, p99 %.1f ms" % (
                kind, len(lat[kind]), len(fails[kind]), q[49] * 1000, q[98] * 1000))
            check(not fails[kind], "%s poller failed: %s" % (kind, fails[kind][:3]))
        ok, over, timeouts = (m.counter(IR_HANDSHAKES_OK), m.counter(IR_FAILED["over_limit"]),
                              m.counter(IR_FAILED["timeout"]))
        # Under emulation (qemu-user, about 14 times slower at crypto) some
        # of the flood's handshakes outlast handshake_timeout_ms and are
        # closed at the deadline, as they should be: they are counted. (A
        # TLS 1.3 client is done before the gateway has checked its
        # certificate: the clients' own count cannot be compared.)
        print("  flood: %d of 200 handshakes completed, %d refused at max_handshakes, "
              "%d closed at the deadline; %d of 64 stalled closed (deadline or room made)" % (
                  sum(results), over, timeouts - 64 if timeouts >= 64 else 0, closed))
        check(closed == 64, "stalled handshakes closed: %d of 64" % closed)
        # The stalled ones are closed at the deadline or, the oldest
        # pending, to make room for the flood: each counted once. One
        # handshake more than the flood: the TLS poller's own.
        check(ok + over + timeouts >= 201 + 64,
              "every handshake completed, was refused or closed at the limit, or timed out: "
              "%d + %d + %d" % (ok, over, timeouts))

        check(m.plain().ir(IR_HANDSHAKES_RUNNING)[0] == 0, "no handshake left running")


EMULATED = bool(os.environ.get("JAKAGW_RUNNER"))


def has_asan():
    from harness import JAKAGW
    return b"libasan" in subprocess.run(["ldd", JAKAGW], capture_output=True).stdout


# A record of handshake type opening a ClientHello of 128 KiB (OpenSSL takes
# up to 131396 bytes), then records of zeros that go on filling it: bytes a
# handshake must buffer, from a client that needs no certificate.
STREAM_FIRST = b"\x16\x03\x01\x40\x00" + b"\x01\x02\x00\x00" + bytes(16380)
STREAM_NEXT = b"\x16\x03\x01\x40\x00" + bytes(16384)


def add(counter, n):
    with counter.get_lock():
        counter.value += n


class Attackers:
    """'count' threads running worker(port, stop, counter), in a process of
    their own: the Python lock they hold does not delay the test's clients
    and pollers, as another host's would not."""

    def __init__(self, worker, port, count):
        mp = multiprocessing.get_context("fork")
        self.stop, self.counter = mp.Event(), mp.Value("q", 0)
        self.proc = mp.Process(target=self._main, args=(worker, port, count))
        self.proc.start()

    def _main(self, worker, port, count):
        threads = [threading.Thread(target=worker, args=(port, self.stop, self.counter))
                   for _ in range(count)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()

    def end(self):
        self.stop.set()
        self.proc.join(10)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()
        return self.counter.value


def stream_into_handshakes(port, stop, sent):
    """Connects, streams records into its pending handshake until the
    gateway closes it, and connects again, until 'stop'."""
    while not stop.is_set():
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=2)
        except OSError:
            time.sleep(0.01)
            continue
        try:
            s.sendall(STREAM_FIRST)
            while not stop.is_set():
                s.sendall(STREAM_NEXT * 4)
                add(sent, 4 * len(STREAM_NEXT))
        except OSError:
            pass
        finally:
            s.close()


def streaming_flood(clients, seconds):
    """'clients' streaming into pending handshakes (max_handshakes as many)
    for 'seconds', while a plain poller reads every 10 ms: the gateway's
    peak RSS and the poller's latencies."""
    edit = lambda c: c.replace("max_handshakes = 16", "max_handshakes = %d" % clients)  # noqa: E731
    # ASan holds freed memory back (256 MiB by default) to catch a use
    # after free: kept small here, so that RSS says what the gateway holds.
    env = None
    if has_asan():
        env = {"ASAN_OPTIONS": os.environ.get("ASAN_OPTIONS", "") + ":quarantine_size_mb=4"}
    with Mbaps(edit=edit, env=env) as m:
        pid = m.gw.proc.pid
        plain = raw_client(m.gw.modbus_port)
        read_input_registers(plain, 18, 2)
        base = rss_kb(pid)
        poll_stop = threading.Event()
        lat, fails = [], []
        poller = threading.Thread(target=poll_loop, args=(
            lambda: read_input_registers(plain, 18, 2), poll_stop, lat, fails))
        poller.start()
        streamers = Attackers(stream_into_handshakes, m.tls_port, clients)
        peak = base
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            peak = max(peak, rss_kb(pid))
            time.sleep(0.02)
        poll_stop.set()
        poller.join()
        sent = streamers.end()
        plain.close()
        q = statistics.quantiles(lat, n=100)
        print("  %d streaming clients, %.1f s: %.0f MiB written; RSS %.1f -> peak %.1f MiB; "
              "plain poller: %d reads, %d failures, p50 %.1f ms, p99 %.1f ms" % (
                  clients, seconds, sent / 1048576, base / 1024, peak / 1024, len(lat),
                  len(fails), q[49] * 1000, q[98] * 1000))
        check(not fails, "the poller failed: %s" % fails[:3])
        check(m.gw.alive(), "the gateway died")
        return base, peak, q[98]


def check_flood(clients):
    base, peak, p99 = streaming_flood(clients, 4)
    # The bound is the for the plain build. ASan's shadow memory
    # and redzones, qemu-user's own memory and its 10-15x slower crypto:
    # the growth is judged there, and the latency bound grows with the
    # emulation.
    if has_asan() or EMULATED:
        check(peak - base < 48 * 1024, "RSS grew by %d KiB" % (peak - base))
    else:
        check(peak < 48 * 1024, "peak RSS %d KiB" % peak)
    # The flood keeps the loop busy reading: a loop that read one socket
    # until it ran dry would not turn for seconds. ASan checks every byte
    # the loop copies, which makes this loop 2-5 times slower (134 ms
    # measured on a loaded machine), so its bound is five times the issue's.
    bound = 0.5 if EMULATED else 0.25 if has_asan() else 0.05
    check(p99 < bound, "plain poller p99 %.1f ms (bound %.0f ms)" % (p99 * 1000, bound * 1000))


def test_16_streaming_handshakes_bounded():
    """16 unauthenticated clients streaming bytes into pending handshakes
    (max_handshakes 16): memory stays bounded and the plain port answered."""
    check_flood(16)


def test_64_streaming_handshakes_bounded():
    check_flood(64)


def churn_idle(port, stop, connects):
    """A TCP connection that sends nothing, reopened as soon as it closes."""
    while not stop.is_set():
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=2)
        except OSError:
            time.sleep(0.005)
            continue
        add(connects, 1)
        s.settimeout(0.5)
        try:
            while not stop.is_set():
                try:
                    if not s.recv(10):
                        break
                except socket.timeout:
                    continue
        except OSError:
            pass
        finally:
            s.close()


def s_client_reads(port, timeout=5 * SLOW):
    """`openssl s_client` with the operator's certificate reads input
    register 0: True when 0x4A4B comes back. A client in C, as a PLC's TLS
    stack is: its ClientHello follows the connect at once."""
    proc = subprocess.Popen(["openssl", "s_client", "-connect", "127.0.0.1:%d" % port, "-quiet",
                             "-CAfile", pki("ca.crt"), "-cert", pki("operator.crt"),
                             "-key", pki("operator.key")],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL)
    try:
        proc.stdin.write(mbap(1, struct.pack(">BHH", 4, 0, 1)))
        proc.stdin.flush()
        data, end = b"", time.monotonic() + timeout
        while len(data) < 11 and time.monotonic() < end:
            ready, _, _ = select.select([proc.stdout], [], [], 0.05)
            if ready:
                chunk = os.read(proc.stdout.fileno(), 64)
                if not chunk:
                    break
                data += chunk
        return len(data) >= 11 and data[9:11] == b"\x4a\x4b"
    except OSError:
        return False
    finally:
        proc.kill()
        proc.wait()


def test_idle_sockets_do_not_lock_out_tls_clients():
    """16 silent sockets that reconnect as soon as they are closed hold
    every handshake slot (max_handshakes 16); new TLS clients still get in,
    from the same address, because a silent one makes room for them."""
    with Mbaps() as m:
        churners = Attackers(churn_idle, m.tls_port, 16)
        try:
            wait_until(lambda: m.plain().ir(IR_HANDSHAKES_RUNNING)[0] == 16, 5 * SLOW,
                       "16 silent sockets holding the handshake slots")
            # Each client tries as a PLC does: connects again when its
            # connection is closed, up to 3 times. A client whose
            # ClientHello this loaded machine holds back is silent for as
            # long, and may be displaced as a silent socket is.
            tries = []
            for _ in range(10):
                for attempt in range(1, 4):
                    if s_client_reads(m.tls_port):
                        tries.append(attempt)
                        break
        finally:
            connects = churners.end()
        first = sum(1 for t in tries if t == 1)
        print("  %d of 10 TLS clients served among 16 churning silent sockets (%d connects), "
              "%d at the first try" % (len(tries), connects, first))
        check(len(tries) == 10, "only %d of 10 TLS clients served in 3 tries" % len(tries))


def test_sighup_rotates_the_certificate():
    cert = pki("rot.crt")
    key = pki("rot.key")
    for src, dst in (("gateway.crt", cert), ("gateway.key", key)):
        with open(pki(src), "rb") as f, open(dst, "wb") as g:
            g.write(f.read())
    os.chmod(key, 0o600)
    with Mbaps(edit=lambda c: c.replace(pki("gateway.crt"), cert).replace(pki("gateway.key"), key)) as m:
        old = tls_socket(m.tls_port, "operator")
        check("CN=jakagw" in str(old.getpeercert()["subject"]) or
              old.getpeercert()["subject"][0][0][1] == "jakagw", "the first certificate")
        read_input_registers(old, 0, 1)
        # A key readable by others: refused with one line, nothing changes.
        for src, dst in (("gateway2.crt", cert), ("gateway2.key", key)):
            with open(pki(src), "rb") as f, open(dst, "wb") as g:
                g.write(f.read())
        os.chmod(key, 0o644)
        m.gw.proc.send_signal(1)
        wait_until(lambda: log_lines(m.gw, "accessible by other users (mode 0644)"), 5 * SLOW,
                   "the refusal")
        check(len(log_lines(m.gw, "accessible by other users")) == 1, m.gw.output())
        s = tls_socket(m.tls_port, "operator")
        check(s.getpeercert()["subject"][0][0][1] == "jakagw", "still the first certificate")
        s.close()
        os.chmod(key, 0o600)
        m.gw.proc.send_signal(1)
        wait_until(lambda: log_lines(m.gw, 'new connections get certificate "CN=gateway2"'), 5 * SLOW,
                   "the reload")
        s = tls_socket(m.tls_port, "operator")
        check(s.getpeercert()["subject"][0][0][1] == "gateway2", "the new certificate")
        s.close()
        check(read_input_registers(old, 0, 1) == [0x4A4B], "the established session goes on")
        old.close()


def test_no_growth_over_1000_handshakes():
    # ASan keeps freed memory in quarantine, so RSS says nothing there; its
    # leak check at exit and the descriptors do, and 200 handshakes show a
    # descriptor or a leak per handshake as well as 1000 (59 s under ASan
    # for 1000).
    from harness import JAKAGW
    asan = b"libasan" in subprocess.run(["ldd", JAKAGW], capture_output=True).stdout
    count = 200 if asan else 1000
    with Mbaps() as m:
        pid = m.gw.proc.pid

        def shake(n):
            for _ in range(n):
                s = tls_socket(m.tls_port, "operator")
                read_input_registers(s, 0, 1)
                s.close()
        shake(100)
        time.sleep(0.3)
        fds, rss = open_fds(pid), rss_kb(pid)
        shake(count)
        time.sleep(0.5)
        fds2, rss2 = open_fds(pid), rss_kb(pid)
        print("  %d handshakes: fds %d -> %d, RSS %d -> %d KiB" % (count, fds, fds2, rss, rss2))
        check(fds2 <= fds, "descriptors grew: %d -> %d" % (fds, fds2))
        check(asan or rss2 - rss < 1024, "RSS grew by %d KiB" % (rss2 - rss))


IR_STATUS_LINK, IR_COMMAND_LINK, IR_STATUS_TASK_STATE = 16, 17, 100
IR_STATUS_TLS_FAILURE, IR_COMMAND_TLS_FAILURE = 96, 97
COIL_POWER_ON = 100


def robot_config(**keys):
    lines = "".join("%s = %s\n" % kv for kv in keys.items())
    return ("[robot]\ntls = true\nconnect_timeout_ms = %d\nreconnect_min_ms = 50\n"
            "reconnect_max_ms = %d\n" % (1000 * SLOW, 200 * SLOW) + lines)


def fingerprint(name):
    out = subprocess.run(["openssl", "x509", "-in", pki(name), "-noout", "-fingerprint",
                          "-sha256"], capture_output=True, text=True, check=True).stdout
    return out.strip().split("=", 1)[1]


def links(gw):
    plc = ModbusPlc(gw.modbus_port)
    try:
        return plc.ir(IR_STATUS_LINK)[0], plc.ir(IR_COMMAND_LINK)[0], \
            plc.ir(IR_STATUS_TLS_FAILURE)[0], plc.ir(IR_COMMAND_TLS_FAILURE)[0]
    finally:
        plc.close()


def test_robot_over_tls():
    """jakasim serving TLS with the robot certificate; the gateway verifying
    it by the CA, or by its pinned fingerprint: status and commands go
    through; a wrong pin, another CA or a plaintext controller is a link
    fault with its reason, logged once while it lasts."""
    sim = Sim("--log-commands", "--tls-cert", pki("robot.crt"), "--tls-key", pki("robot.key"))
    try:
        for how in (dict(tls_ca=pki("ca.crt")), dict(tls_fingerprint=fingerprint("robot.crt")),
                    dict(tls_ca=pki("ca.crt"), tls_fingerprint=fingerprint("robot.crt"))):
            gw = Gateway(sim, robot_config(**how))
            try:
                wait_until(lambda: links(gw) == (2, 2, 0, 0), 10 * SLOW, "both links up over TLS")
                plc = ModbusPlc(gw.modbus_port)
                wait_until(lambda: plc.ir(IR_STATUS_TASK_STATE)[0] in (1, 2, 3, 4), 5 * SLOW,
                           "a status document through TLS")
                wait_until(lambda: plc.ir(IR_ROBOT_HANDLE)[0] == 2, 10 * SLOW,
                           "the robot's handler, through the command port")
                before = len(sim_commands(sim, "power_on"))
                check(plc.pulse(COIL_POWER_ON) == 0, "power_on written")
                wait_until(lambda: len(sim_commands(sim, "power_on")) == before + 1, 5 * SLOW,
                           "power_on at the robot, once")
                wait_until(lambda: plc.ir(IR_STATUS_TASK_STATE)[0] == 2, 5 * SLOW,
                           "the robot powered on, seen through the status port")
                plc.close()
                check(log_lines(gw, "robot links: TLS"), gw.output())
            finally:
                gw.stop()
        # A wrong pin, another CA: the handshake fails, the link stays down
        # with the reason readable, and the log says it once.
        for how, reason, text in (
                (dict(tls_fingerprint="00" * 32), 8, "fingerprint mismatch"),
                (dict(tls_ca=pki("other-ca.crt")), 2, "certificate not trusted")):
            sent = len(sim_commands(sim))
            gw = Gateway(sim, robot_config(**how))
            try:
                wait_until(lambda: links(gw)[2:] == (reason, reason), 10 * SLOW,
                           "the TLS failure reported")
                connects = len(log_lines(sim, "status client connected"))
                wait_until(lambda: len(log_lines(sim, "status client connected")) >= connects + 2,
                           5 * SLOW, "the gateway to retry twice more")
                check(links(gw)[0] != 2 and links(gw)[1] != 2, "no link is up")
                check(len(log_lines(gw, "status link: TLS handshake")) == 1 and
                      text in gw.output(), gw.output())
                check(len(sim_commands(sim)) == sent, "nothing reached the robot")
            finally:
                gw.stop()
        # SIGHUP: a CA file that does not load changes nothing; then the
        # right fingerprint brings both links up, without a restart.
        gw = Gateway(sim, robot_config(tls_fingerprint="00" * 32))
        try:
            wait_until(lambda: links(gw)[2:] == (8, 8), 10 * SLOW, "the wrong pin reported")
            with open(gw.conf.name, "w") as f:
                f.write(robot_config(tls_ca=pki("missing-ca.crt")))
            gw.proc.send_signal(1)
            wait_until(lambda: [l for l in log_lines(gw, "reload refused") if "[robot] tls_ca:" in l],
                       5 * SLOW, "the refused reload to name [robot] tls_ca")
            check(links(gw)[2:] == (8, 8) and gw.alive(), "a failed reload changed nothing")
            with open(gw.conf.name, "w") as f:
                f.write(robot_config(tls_fingerprint=fingerprint("robot.crt")))
            gw.proc.send_signal(1)
            wait_until(lambda: links(gw) == (2, 2, 0, 0), 10 * SLOW,
                       "both links up with the reloaded pin")
            check(log_lines(gw, "reload: robot links (next connections): TLS"), gw.output())
        finally:
            gw.stop()
    finally:
        sim.stop()
    # A controller that speaks plain TCP to a gateway that expects TLS: its
    # status port pushes JSON where a ServerHello should be (protocol); its
    # command port waits for a request and never answers the ClientHello
    # (timeout, after connect_timeout_ms).
    plain = Sim("--log-commands")
    try:
        gw = Gateway(plain, robot_config(tls_ca=pki("ca.crt")))
        try:
            wait_until(lambda: links(gw)[2:] == (5, 6), 10 * SLOW, "protocol and timeout reported")
            check(links(gw)[:2] != (2, 2), "no link is up")
            # The ClientHello's random bytes may hold a '{' that jakasim's
            # framer takes for the start of a request: no command, though.
            check(not [e for e in sim_events(plain) if e[0] == "command" and e[1]],
                  "no command reached the robot")
        finally:
            gw.stop()
    finally:
        plain.stop()


def test_check_config_names_the_key():
    bad = tls_config(802).replace(pki("gateway.key"), pki("operator.key"))
    with tempfile.NamedTemporaryFile("w", suffix=".conf", delete=False) as f:
        f.write(bad)
    try:
        from harness import JAKAGW
        r = subprocess.run([JAKAGW, "-c", f.name, "--check-config"], capture_output=True,
                           text=True)
        check(r.returncode == 2, "exit %d" % r.returncode)
        lines = r.stderr.strip().splitlines()
        check(len(lines) == 1 and "[tls] private_key:" in lines[0] and
              "does not match" in lines[0], r.stderr)
        with open(f.name, "w") as g:
            g.write("[tls]\nenabled = true\ncertificate = %s\n" % pki("gateway.crt"))
        r = subprocess.run([JAKAGW, "-c", f.name, "--check-config"], capture_output=True,
                           text=True)
        check(r.returncode == 2 and "[tls] private_key: required" in r.stderr, r.stderr)
        # [robot] tls: the CA file must load; something must be trusted.
        for text, expect in (("tls_ca = %s\n" % pki("missing.crt"), "[robot] tls_ca: "),
                             ("", "[robot] tls: true needs tls_ca or tls_fingerprint"),
                             ("tls_fingerprint = 12:34\n", "[robot] tls_fingerprint: ")):
            with open(f.name, "w") as g:
                g.write("[robot]\ntls = true\n" + text)
            r = subprocess.run([JAKAGW, "-c", f.name, "--check-config"], capture_output=True,
                               text=True)
            lines = r.stderr.strip().splitlines()
            check(r.returncode == 2 and len(lines) == 1 and expect in lines[0], r.stderr)
        with open(f.name, "w") as g:
            g.write("[robot]\ntls = true\ntls_ca = %s\n" % pki("ca.crt"))
        r = subprocess.run([JAKAGW, "-c", f.name, "--check-config"], capture_output=True,
                           text=True)
        check(r.returncode == 0, r.stderr)
    finally:
        os.unlink(f.name)


if __name__ == "__main__":
    tests = [test_security_doc_word_for_word, test_roles_decide_writes,
             test_plain_client_never_acts_with_a_tls_owners_rights,
             test_refused_handshakes_answer_nothing, test_old_versions_and_plaintext_refused,
             test_renegotiation_refused, test_gateway_closes_end_with_close_notify,
             test_session_lines_rate_limited, test_handshake_flood_does_not_starve_pollers,
             test_16_streaming_handshakes_bounded, test_64_streaming_handshakes_bounded,
             test_idle_sockets_do_not_lock_out_tls_clients,
             test_sighup_rotates_the_certificate, test_no_growth_over_1000_handshakes,
             test_robot_over_tls, test_check_config_names_the_key]
    if sys.argv[1:] == ["valgrind"]:
        # make valgrind: every TLS path but the load tests, whose
        # handshakes cannot finish within their deadline 20-50x slower
        # (valgrind's own leak check at exit stands for the growth test).
        tests = [t for t in tests if t not in (test_handshake_flood_does_not_starve_pollers,
                                               test_16_streaming_handshakes_bounded,
                                               test_64_streaming_handshakes_bounded,
                                               test_idle_sockets_do_not_lock_out_tls_clients,
                                               test_no_growth_over_1000_handshakes)]
    elif sys.argv[1:]:
        # Named tests only: test_tls.py test_renegotiation_refused ...
        tests = [t for t in tests if t.__name__ in sys.argv[1:]]
    try:
        run(tests)
    finally:
        subprocess.run(["rm", "-rf", PKI])
