#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The Modbus TCP slave as a PLC sees it: framing, pipelining, exceptions,
writes, identification, client limits. Byte-exact requests go over raw
sockets; mbpoll and pymodbus check that independent masters agree."""
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

from pymodbus.client import ModbusTcpClient

import harness
from harness import (ModbusPlc, TestFailure, check, mbap, raw_client, read_bits,
                     read_input_registers, recv_adu, run, running, wait_until)


def start(config=""):
    return running(["--test-pattern"], config)


def expect_exception(sock, tid, pdu, function, code):
    sock.sendall(mbap(tid, pdu))
    rtid, _, reply = recv_adu(sock)
    check(rtid == tid, "tid %d, expected %d" % (rtid, tid))
    check(reply == bytes([function | 0x80, code]),
          "request %s: reply %s, expected exception %02x" % (pdu.hex(), reply.hex(), code))


def closed_by_server(sock, timeout):
    sock.settimeout(timeout)
    try:
        while True:
            data = sock.recv(4096)
            if not data:
                return True
    except ConnectionResetError:
        return True
    except socket.timeout:
        return False


def test_stalled_half_request_delays_nobody():
    with start("[modbus]\nframe_timeout_ms = 3000\n") as (sim, gw):
        stalled = raw_client(gw.modbus_port)
        stalled.sendall(mbap(1, struct.pack(">BHH", 4, 0, 10))[:6])  # half a request
        other = raw_client(gw.modbus_port)
        t0 = time.monotonic()
        worst = 0.0
        for i in range(200):
            t = time.monotonic()
            regs = read_input_registers(other, 0, 20, tid=i + 1)
            worst = max(worst, time.monotonic() - t)
            check(regs[0] == 0x4A4B, "magic register %04x" % regs[0])
        elapsed = time.monotonic() - t0
        print("  200 reads beside a stalled client: %.3f s in all, slowest %.1f ms"
              % (elapsed, worst * 1000))
        # All of them finished while the stalled request was still pending.
        check(elapsed < 3.0, "reads took %.2f s: they waited for the stalled client" % elapsed)
        check(not closed_by_server(stalled, 0.05), "stalled client closed too early")
        check(closed_by_server(stalled, 5), "the stalled half request was never timed out")
        check("request incomplete after" in gw.output(), "no log line for the stalled request")
        # The other client is unaffected and still served.
        check(read_input_registers(other, 0, 1, tid=999)[0] == 0x4A4B, "other client broken")
        other.close()
        stalled.close()


def test_pipelined_requests_answered_in_order():
    with start() as (sim, gw):
        s = raw_client(gw.modbus_port)
        burst = (mbap(10, struct.pack(">BHH", 4, 0, 2))            # valid
                 + mbap(11, bytes([0x07]))                          # unsupported function
                 + mbap(12, struct.pack(">BHH", 4, 0, 126))         # bad quantity
                 + mbap(13, struct.pack(">BHH", 4, 0xFFF0, 2))      # bad address
                 + mbap(14, struct.pack(">BHH", 2, 17, 1))          # valid: enabled bit
                 + mbap(15, struct.pack(">BHH", 6, 0, 0x1234)[:4]))  # short PDU
        s.sendall(burst)
        replies = [recv_adu(s) for _ in range(6)]
        check([r[0] for r in replies] == [10, 11, 12, 13, 14, 15],
              "order %s" % [r[0] for r in replies])
        check(replies[0][2][:2] == b"\x04\x04" and replies[0][2][2:4] == b"\x4a\x4b",
              "first reply %s" % replies[0][2].hex())
        check(replies[1][2] == b"\x87\x01", "unsupported function: %s" % replies[1][2].hex())
        check(replies[2][2] == b"\x84\x03", "bad quantity: %s" % replies[2][2].hex())
        check(replies[3][2] == b"\x84\x02", "bad address: %s" % replies[3][2].hex())
        check(replies[4][2][:2] == b"\x02\x01", "discrete input reply %s" % replies[4][2].hex())
        check(replies[5][2] == b"\x86\x03", "short PDU: %s" % replies[5][2].hex())
        # The connection stays usable after exceptions.
        check(read_input_registers(s, 1, 1, tid=16)[0] == 1, "map version")
        s.close()


def test_exceptions_for_bad_requests():
    with start() as (sim, gw):
        s = raw_client(gw.modbus_port)
        expect_exception(s, 1, struct.pack(">BHH", 3, 9000, 1), 3, 2)      # past HR table
        expect_exception(s, 2, struct.pack(">BHH", 6, 5, 1), 6, 2)         # not writable
        expect_exception(s, 3, struct.pack(">BHH", 5, 0, 0x1234), 5, 3)    # coil value
        expect_exception(s, 4, struct.pack(">BHHB", 16, 0, 1, 4) + b"\0\0\0\0", 16, 3)
        expect_exception(s, 5, struct.pack(">BHHB", 15, 0, 1, 1) + b"\x01\x00", 15, 3)
        expect_exception(s, 6, bytes([0x2B, 0x0E, 0x07, 0x00]), 0x2B, 3)   # bad read code
        expect_exception(s, 7, bytes([0x2B, 0x0E, 0x04, 0x33]), 0x2B, 2)   # no such object
        expect_exception(s, 8, bytes([0x08, 0, 0, 0x12, 0x34]), 0x08, 1)   # diagnostics
        s.close()
        # The first refusal is logged with what was asked and why; a burst
        # of them is rate-limited, not one line each.
        out = gw.output()
        check("request refused: unit 1 function 3 address 9000 quantity/value 1: exception 02 "
              "(illegal data address)" in out, "no log line for the refusal:\n" + out)
        check(out.count("request refused") < 4, "refusals are not rate-limited:\n" + out)


def test_writes_heartbeat_and_clear_counters():
    with start() as (sim, gw):
        c = ModbusTcpClient("127.0.0.1", port=gw.modbus_port, timeout=5)
        check(c.connect(), "connect")
        age = lambda: (lambda r: r[0] << 16 | r[1])(c.read_input_registers(48, 2, slave=1).registers)
        check(age() == 0xFFFFFFFF, "heartbeat age before any write")
        check(not c.write_register(0, 7, slave=1).isError(), "FC6")
        check(c.read_holding_registers(0, 1, slave=1).registers == [7], "FC3 after FC6")
        check(age() < 1000, "heartbeat age after a write: %d" % age())
        check(not c.write_registers(0, [8], slave=1).isError(), "FC16")
        rr = c.readwrite_registers(read_address=0, read_count=1, write_address=0,
                                   write_registers=[9], slave=1)
        check(not rr.isError() and rr.registers == [9], "FC23: %s" % rr)
        check(not c.mask_write_register(0, 0x00F0, 0x0003, slave=1).isError(), "FC22")
        check(c.read_holding_registers(0, 1, slave=1).registers == [(9 & 0xF0) | (3 & ~0xF0)],
              "FC22 result")
        requests = lambda: (lambda r: r[0] << 16 | r[1])(c.read_input_registers(36, 2, slave=1).registers)
        check(requests() > 5, "request counter")
        check(not c.write_coil(0, True, slave=1).isError(), "FC5")
        check(requests() <= 2, "counters not cleared: %d" % requests())
        check(c.read_coils(0, 1, slave=1).bits[0] is False, "command coil reads 0 afterwards")
        check(not c.write_coils(0, [True], slave=1).isError(), "FC15")
        check("counters cleared" in gw.output(), "no log line for clearing counters")
        c.close()


def test_identification_17_and_43():
    with start() as (sim, gw):
        s = raw_client(gw.modbus_port)
        wait_until(lambda: read_bits(s, 2, 2, 1)[0] == 1, 10, "fresh status")
        s.sendall(mbap(1, bytes([0x11]), unit=9))
        tid, unit, pdu = recv_adu(s)
        check(unit == 9 and pdu[0] == 0x11, "FC17 reply %s" % pdu.hex())
        check(pdu[3] == 0xFF, "run indicator should be ON with live data")
        check(b"jakagw" in pdu[4:], "FC17 text %r" % pdu[4:])
        s.sendall(mbap(2, bytes([0x2B, 0x0E, 0x03, 0x00])))
        _, _, pdu = recv_adu(s)
        objects, p = {}, 7
        for _ in range(pdu[6]):
            objects[pdu[p]] = pdu[p + 2:p + 2 + pdu[p + 1]].decode()
            p += 2 + pdu[p + 1]
        check(objects.get(0) == "jakagw", "vendor %r" % objects)
        check(objects.get(2) == "0.1.0", "revision %r" % objects)
        check(objects.get(0x80, "").startswith("map 1 crc "), "map version object %r" % objects)
        s.sendall(mbap(3, bytes([0x2B, 0x0E, 0x04, 0x80])))
        _, _, pdu = recv_adu(s)
        check(pdu[6] == 1 and pdu[7] == 0x80, "individual access %s" % pdu.hex())
        s.close()


def test_full_server_evicts_the_longest_idle():
    with start("[modbus]\nmax_clients = 32\n") as (sim, gw):
        clients = []
        for i in range(32):
            c = raw_client(gw.modbus_port)
            read_input_registers(c, 0, 1, tid=i)
            clients.append(c)
            time.sleep(0.005)
        # Client 0 is now the longest idle; 1..31 read again, 2 ms apart so
        # that their idle times are distinct.
        for i, c in enumerate(clients[1:], 1):
            read_input_registers(c, 0, 1, tid=100 + i)
            time.sleep(0.002)
        newcomer = raw_client(gw.modbus_port)
        check(read_input_registers(newcomer, 0, 1, tid=7)[0] == 0x4A4B, "newcomer not served")
        check(closed_by_server(clients[0], 3), "the longest idle client was not evicted")
        # Eight more newcomers: each evicts the longest idle (clients 1..8),
        # nobody is refused.
        later = []
        for i in range(8):
            time.sleep(0.002)
            n = raw_client(gw.modbus_port)
            check(read_input_registers(n, 0, 1, tid=300 + i)[0] == 0x4A4B, "newcomer %d" % i)
            later.append(n)
        for i in range(1, 9):
            check(closed_by_server(clients[i], 3), "client %d was not evicted" % i)
        for i in range(9, 32):
            read_input_registers(clients[i], 0, 1, tid=400 + i)  # still served
        read_input_registers(newcomer, 0, 1, tid=8)
        count = read_input_registers(newcomer, 40, 1, tid=9)[0]
        check(count == 32, "clients register %d, expected 32" % count)
        evictions = read_input_registers(newcomer, 42, 2, tid=10)
        check(evictions[1] == 9, "evictions %s" % evictions)
        check("evicted after" in gw.output(), "no log line for eviction")
        for c in clients + later + [newcomer]:
            c.close()


class Poller:
    """A PLC on its own thread: reads the client count and the eviction
    counter (input registers 40-43) every 10 ms, and counts what went wrong.
    A closed connection counts as an eviction; the poller reconnects."""

    def __init__(self, port, period=0.01):
        self.port, self.period = port, period
        self.polls = self.failures = self.evicted = 0
        self.clients = self.evictions = None
        self.errors = []
        self._stop = threading.Event()
        self._sock = raw_client(port)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        tid = 0
        while not self._stop.is_set():
            tid = (tid + 1) & 0xFFFF
            try:
                regs = read_input_registers(self._sock, 40, 4, tid=tid)
                self.clients, self.evictions = regs[0], regs[2] << 16 | regs[3]
                self.polls += 1
            except Exception as e:  # a failed poll: record it, reconnect
                self.failures += 1
                self.errors.append("%s: %s" % (type(e).__name__, e))
                if isinstance(e, (TestFailure, ConnectionError)):
                    self.evicted += 1
                self._sock.close()
                try:
                    self._sock = raw_client(self.port)
                except OSError as e2:
                    self.errors.append("reconnect: %s" % e2)
            self._stop.wait(self.period)

    def wait_polls(self, n, what="the poller"):
        target = self.polls + n
        wait_until(lambda: self.polls >= target or self.failures, 10, what)

    def stop(self):
        self._stop.set()
        self._thread.join(10)
        self._sock.close()


def silent_burst(port, n):
    """n connections that never send anything, opened as fast as possible."""
    return [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(n)]


def test_active_poller_survives_connect_bursts():
    with start("[modbus]\nmax_clients = 32\n") as (sim, gw):
        poller = Poller(gw.modbus_port)
        bursts = [33] * 20 + [100]
        expected, bursts_evicting_poller, excess = 0, 0, []
        try:
            for i, n in enumerate(bursts):
                poller.wait_polls(2)  # bursts at varying phases of the poll period
                evicted_before = poller.evicted
                burst = silent_burst(gw.modbus_port, n)
                # The poller and the burst need n + 1 - 32 evictions: no
                # more, so the previous burst, closed just before this one
                # started, counted for nothing.
                expected += n + 1 - 32
                wait_until(lambda: poller.evicted > evicted_before
                           or (poller.evictions or 0) >= expected, 10,
                           "%d evictions" % expected)
                poller.wait_polls(2)
                for s in burst:
                    s.close()
                if poller.evicted > evicted_before:
                    bursts_evicting_poller += 1
                if poller.evictions != expected:
                    excess.append((i, poller.evictions - expected))
                    expected = poller.evictions
        finally:
            poller.stop()
        print("  %d polls; poller evicted in %d of %d bursts, %d failed polls; "
              "bursts with evictions beyond need: %s"
              % (poller.polls, bursts_evicting_poller, len(bursts), poller.failures, excess))
        check(poller.evicted == 0 and poller.failures == 0,
              "the active poller was evicted in %d of %d bursts, %d polls failed: %s"
              % (bursts_evicting_poller, len(bursts), poller.failures, poller.errors[:3]))
        check(not excess, "(burst, evictions beyond need): %s" % excess)


def test_buffered_requests_and_closed_peers_before_eviction():
    """While the gateway is held (SIGSTOP), the kernel completes the
    connections and buffers their bytes: 12 clients send a request and
    shut down their write side, 20 connect and close, 30 connect silently.
    Released, the gateway finds 62 connections waiting: every request it has
    received is answered, and the closed ones do not count toward
    max_clients, so nothing needs evicting."""
    with start("[modbus]\nmax_clients = 32\n") as (sim, gw):
        poller = Poller(gw.modbus_port)
        held = []
        try:
            poller.wait_polls(2)
            gw.proc.send_signal(signal.SIGSTOP)
            try:
                half_closed = []
                for i in range(12):
                    s = raw_client(gw.modbus_port)
                    s.sendall(mbap(500 + i, struct.pack(">BHH", 4, 0, 1)))
                    s.shutdown(socket.SHUT_WR)
                    half_closed.append(s)
                for s in silent_burst(gw.modbus_port, 20):
                    s.close()
                held = silent_burst(gw.modbus_port, 30)
            finally:
                gw.proc.send_signal(signal.SIGCONT)
            answered = 0
            for i, s in enumerate(half_closed):
                try:
                    tid, _, pdu = recv_adu(s)
                    answered += tid == 500 + i and pdu[:4] == b"\x04\x02\x4a\x4b"
                except (TestFailure, OSError):
                    pass
                s.close()
            poller.wait_polls(3)
        finally:
            poller.stop()
            for s in held:
                s.close()
        print("  half-closed clients answered: %d of 12; evictions %s; poller evicted %d"
              % (answered, poller.evictions, poller.evicted))
        check(answered == 12, "%d of 12 half-closed clients got their answer" % answered)
        check(poller.evicted == 0 and poller.failures == 0,
              "the poller was evicted: %s" % poller.errors[:3])
        check(poller.evictions == 0, "%s evictions with only 31 live clients"
              % poller.evictions)
        check(poller.clients == 31, "clients register %s, expected 31" % poller.clients)


def test_reserved_function_codes_close_the_connection():
    # Codes 128-255 mark exception responses; no exception reply to them
    # exists (bit 7 is already set), so the gateway closes the connection
    # after answering what came before, whatever the unit id.
    for config, unit in (("", 1), ("[modbus]\nunit_id = 5\n", 1)):
        with start(config) as (sim, gw):
            for function in (0x80, 0x84, 0xAB, 0xFF):
                s = raw_client(gw.modbus_port)
                s.sendall(mbap(1, struct.pack(">BHH", 4, 0, 1), unit=5)
                          + mbap(2, struct.pack(">BHH", function, 0, 1), unit=unit)
                          + mbap(3, struct.pack(">BHH", 4, 0, 1), unit=5))
                tid, _, pdu = recv_adu(s)
                check(tid == 1 and pdu[:2] == b"\x04\x02", "first reply %d %s" % (tid, pdu.hex()))
                extra, closed = b"", False
                s.settimeout(5)
                try:
                    while not closed:
                        chunk = s.recv(4096)
                        extra += chunk
                        closed = not chunk
                except ConnectionResetError:
                    closed = True
                except socket.timeout:
                    pass
                check(extra == b"" and closed, "function %02x (%s): answered %s, %s"
                      % (function, config.strip() or "any unit", extra.hex() or "nothing",
                         "closed" if closed else "left open"))
                s.close()
            # Function 0 is invalid too, but its exception reply (80 01) is
            # well-formed: answered, and the connection stays usable.
            s = raw_client(gw.modbus_port)
            expect_exception(s, 9, bytes([0x00]), 0x00, 1 if not config else 0x0A)
            s.sendall(mbap(10, struct.pack(">BHH", 4, 0, 1), unit=5))
            check(recv_adu(s)[0] == 10, "connection unusable after function 0")
            s.close()
            check("reserved for exception responses" in gw.output(), "no log line")


# How far from the 1 s deadline the test's early and late requests go. The
# gateway's clock for a frame starts when its loop reads the first bytes;
# under qemu-user on a busy machine that read can come 100 ms or more
# after the client sent them (1 of 6 "late" requests was answered at
# 1.1 s client time), so emulated runs judge the deadline at +-0.3 s.
MARGIN = 0.3 if harness.RUNNER else 0.1


def timed_completions(port, first, second, answers_first):
    """Twelve connections, started 20 ms apart: each sends 'first' (and
    reads its answer if 'answers_first'), then 'second' 1 s - MARGIN (even
    ones) or 1 s + MARGIN (odd ones) later. Returns (late and answered, on
    time and refused, on time but this client was itself late), as gaps
    in s."""
    socks = [raw_client(port) for _ in range(12)]
    events = [(time.monotonic() + 0.02 * i, "first", i) for i in range(12)]
    started, gaps = {}, {}
    while events:
        events.sort(key=lambda e: e[0])
        when, kind, i = events.pop(0)
        pause = when - time.monotonic()
        if pause > 0:
            time.sleep(pause)  # the test is about time: act at the moment
        delay = 1 + MARGIN if i % 2 else 1 - MARGIN
        if kind == "first":
            started[i] = time.monotonic()
            socks[i].sendall(first)
            if answers_first:
                check(recv_adu(socks[i])[0] == 1, "first request not answered")
            events.append((started[i] + delay, "second", i))
        else:
            try:
                socks[i].sendall(second)
            except OSError:
                pass  # already closed by the gateway: that is a refusal
            gaps[i] = time.monotonic() - started[i]
    late_answered, on_time_refused, client_late = [], [], 0
    for i, s in enumerate(socks):
        try:
            tid, _, pdu = recv_adu(s)
            answered = tid == 2 and pdu[:2] == b"\x04\x02"
        except (TestFailure, OSError):
            answered = False
        s.close()
        if i % 2 and answered:
            late_answered.append(round(gaps[i], 3))
        elif not i % 2 and not answered:
            if gaps[i] > 1 - MARGIN + 0.07:
                client_late += 1
            else:
                on_time_refused.append(round(gaps[i], 3))
    return late_answered, on_time_refused, client_late


def check_timed_completions(what, result):
    late_answered, on_time_refused, client_late = result
    print("  %s: after %.1f s answered %d of 6; after %.1f s refused %d of 6 (%d sent late)"
          % (what, 1 + MARGIN, len(late_answered), 1 - MARGIN, len(on_time_refused),
             client_late))
    check(not late_answered, "%s: answered after %s s" % (what, late_answered))
    check(not on_time_refused, "%s: refused after %s s" % (what, on_time_refused))
    check(client_late < 3, "%s: the test client itself was late %d times" % (what, client_late))


def test_frame_deadline_is_precise():
    """frame_timeout_ms = 1000: a request completed 1.1 s after its first
    byte is refused (connection closed, no answer), one completed after
    0.9 s is answered (1.3 and 0.7 s under qemu-user: MARGIN)."""
    with start("[modbus]\nframe_timeout_ms = 1000\n") as (sim, gw):
        request = mbap(2, struct.pack(">BHH", 4, 0, 1))
        check_timed_completions("request completed",
                                timed_completions(gw.modbus_port, request[:5], request[5:],
                                                  False))


def test_idle_timeout_is_precise():
    """idle_timeout_ms = 1000: a client that polls again 1.1 s after its
    last request has been closed; one that polls after 0.9 s is answered
    (1.3 and 0.7 s under qemu-user: MARGIN)."""
    with start("[modbus]\nidle_timeout_ms = 1000\n") as (sim, gw):
        check_timed_completions("next request",
                                timed_completions(gw.modbus_port,
                                                  mbap(1, struct.pack(">BHH", 4, 0, 1)),
                                                  mbap(2, struct.pack(">BHH", 4, 0, 1)), True))


def test_bad_header_closes_only_that_connection():
    with start() as (sim, gw):
        good = raw_client(gw.modbus_port)
        bad = raw_client(gw.modbus_port)
        bad.sendall(struct.pack(">HHHB", 1, 7, 6, 1) + b"\x04\x00\x00\x00\x01")
        check(closed_by_server(bad, 3), "bad protocol id not closed")
        bad = raw_client(gw.modbus_port)
        bad.sendall(struct.pack(">HHHB", 1, 0, 1000, 1))
        check(closed_by_server(bad, 3), "bad length not closed")
        check(read_input_registers(good, 0, 1)[0] == 0x4A4B, "good client broken")
        good.close()


def test_unit_id_filter_and_idle_timeout():
    with start("[modbus]\nunit_id = 5\nidle_timeout_ms = 400\n") as (sim, gw):
        s = raw_client(gw.modbus_port)
        s.sendall(mbap(1, struct.pack(">BHH", 4, 0, 1), unit=1))
        _, _, pdu = recv_adu(s)
        check(pdu == b"\x84\x0a", "other unit: %s" % pdu.hex())
        s.sendall(mbap(2, struct.pack(">BHH", 4, 0, 1), unit=5))
        _, unit, pdu = recv_adu(s)
        check(unit == 5 and pdu[:2] == b"\x04\x02", "own unit: %s" % pdu.hex())
        check(closed_by_server(s, 3), "idle client not closed")
        check("idle for" in gw.output(), "no log line for the idle close")


def test_mbpoll_reads_live_status():
    with start() as (sim, gw):
        out = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(gw.modbus_port), "-t", "3",
                              "-r", "1", "-c", "20", "-1", "127.0.0.1"],
                             capture_output=True, text=True, timeout=20)
        check(out.returncode == 0, "mbpoll failed: %s %s" % (out.stdout, out.stderr))
        check("[1]: \t19019" in out.stdout, "mbpoll did not read the magic 0x4A4B:\n" + out.stdout)
        out = subprocess.run(["mbpoll", "-m", "tcp", "-p", str(gw.modbus_port), "-t", "3:float",
                              "-B", "-r", "7", "-c", "1", "-1", "127.0.0.1"],
                             capture_output=True, text=True, timeout=20)
        check("[7]: \t-1234.5" in out.stdout, "mbpoll float probe:\n" + out.stdout)


IR_MODBUS_CLIENTS = 40


def pulled_plc():
    """In a network namespace of its own (see below): a PLC's packets are
    dropped, as when its cable is pulled, and it says nothing more.
    Keepalive (2 s, then 3 probes 1 s apart) ends its connection: the
    gateway counts one client less (and whatever that PLC owned goes by
    the path of any closed client)."""
    with running() as (sim, gw):
        pulled, other = ModbusPlc(gw.modbus_port), ModbusPlc(gw.modbus_port)
        check(pulled.ir(0)[0] == 0x4A4B, "the PLC reads")
        check(other.ir(IR_MODBUS_CLIENTS)[0] == 2, "two clients")
        port = pulled.client.socket.getsockname()[1]
        for rule in (["add", "table", "inet", "pulled"],
                     ["add", "chain", "inet", "pulled", "out",
                      "{ type filter hook output priority 0; }"],
                     ["add", "rule", "inet", "pulled", "out", "tcp", "sport", str(port), "drop"]):
            subprocess.run(["nft"] + rule, check=True)
        start = time.monotonic()
        wait_until(lambda: other.ir(IR_MODBUS_CLIENTS)[0] == 1, 30,
                   "the pulled PLC's connection to close")
        elapsed = time.monotonic() - start
        print("  the pulled PLC's connection closed after %.1f s" % elapsed)
        check(elapsed < 8, "closed after %.1f s" % elapsed)
        other.close()


def test_pulled_plc_frees_its_slot_within_seconds():
    """A PLC pulled off the network without a word frees its connection in
    about 5 s (TCP keepalive and TCP_USER_TIMEOUT), not the kernel's
    minutes. Needs a network namespace (root, ip, nft) to
    drop its packets without touching the host's."""
    if os.geteuid() != 0 or not (shutil.which("ip") and shutil.which("nft")):
        print("  skipped: needs root, ip and nft for a network namespace")
        return
    # unshare -n rather than ip netns: a named namespace needs a mount of
    # /run/netns, which a chroot (CI's) cannot make.
    r = subprocess.run(["unshare", "-n", "--", "sh", "-c",
                        'ip link set lo up && exec "$0" "$1" pulled-plc',
                        sys.executable, os.path.abspath(__file__)],
                       capture_output=True, text=True, timeout=120)
    print(r.stdout.rstrip())
    check(r.returncode == 0, "in the namespace:\n%s%s" % (r.stdout, r.stderr[-3000:]))

if __name__ == "__main__":
    if sys.argv[1:] == ["pulled-plc"]:
        run([pulled_plc])
    tests = [test_stalled_half_request_delays_nobody, test_pipelined_requests_answered_in_order,
             test_exceptions_for_bad_requests, test_writes_heartbeat_and_clear_counters,
             test_identification_17_and_43, test_full_server_evicts_the_longest_idle,
             test_bad_header_closes_only_that_connection, test_unit_id_filter_and_idle_timeout,
             test_mbpoll_reads_live_status, test_active_poller_survives_connect_bursts,
             test_buffered_requests_and_closed_peers_before_eviction,
             test_reserved_function_codes_close_the_connection, test_frame_deadline_is_precise,
             test_idle_timeout_is_precise, test_pulled_plc_frees_its_slot_within_seconds]
    if sys.argv[1:] == ["valgrind"]:
        # make valgrind: the two deadline-precision tests measure +-100 ms,
        # which valgrind's 20-50x slowdown cannot keep; make test runs them.
        tests = [t for t in tests
                 if t not in (test_frame_deadline_is_precise, test_idle_timeout_is_precise)]
    elif sys.argv[1:]:
        tests = [t for t in tests if t.__name__ in sys.argv[1:]]  # named tests only
    run(tests)
