#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Abuse: what hostile or broken clients do to the Modbus server, while four
well-behaved clients poll it every 20 ms.

- a flood of 200 connections that never send anything, far over
  max_clients (16 here);
- 64 clients that each send part of a request and stall (slowloris);
- malformed MBAP headers: length 0, length 300 (over the 260-byte ADU),
  protocol id 1;
- clients from 127.0.0.2 and 127.0.0.3, not in write_allow, writing.

jakagw must evict the idle connections (never a poller), close every
stalled one within frame_timeout_ms, close the connection on a malformed
header, refuse the writes with exception 01 while still answering those
clients' reads, fail no poller request, keep every poller's wait under
250 ms, and end with as many open descriptors as it started with.

The same abuse then runs against bench/ref_slave (plain libmodbus: one
select() loop around modbus_receive() and modbus_reply(), a mapping of
jakagw's size), and a table shows what each did. Only jakagw's behaviour
is asserted; the reference's is reported. REF_SLAVE names the reference
binary (default: JAKAGW_BIN_DIR/bench/ref_slave, then build/bench/ref_slave);
without one, the table has jakagw's column only.
"""
import os
import select
import socket
import struct
import subprocess
import threading
import time

from harness import (BIN, TestFailure, check, free_port, map_rows, mbap, port_open, run,
                     running, wait_until)

MAX_CLIENTS = 16
FRAME_TIMEOUT_MS = 1000
POLLERS = 4
POLL_PERIOD = 0.02
FLOOD = 200
SLOWLORIS = 64
STARVED_S = 0.25  # a poller that waits longer than this was starved
CONFIG = ("[modbus]\nmax_clients = %d\nframe_timeout_ms = %d\nwrite_allow = 127.0.0.1\n"
          % (MAX_CLIENTS, FRAME_TIMEOUT_MS))
READ_PDU = struct.pack(">BHH", 4, 0, 10)


def open_fds(pid):
    return len(os.listdir("/proc/%d/fd" % pid))


def connect(port, source="127.0.0.1", timeout=5):
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.settimeout(timeout)
    s.bind((source, 0))
    s.connect(("127.0.0.1", port))
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def recv_reply(sock):
    """One reply ADU, or None when the server closed the connection."""
    data = b""
    while len(data) < 7 or len(data) < 6 + struct.unpack(">H", data[4:6])[0]:
        chunk = sock.recv(512)
        if not chunk:
            return None
        data += chunk
    return data


def closed_by_server(sock):
    """True once the peer has closed (EOF or reset); never blocks."""
    poller = select.poll()
    poller.register(sock, select.POLLIN)
    if not poller.poll(0):
        return False
    try:
        return sock.recv(512, socket.MSG_PEEK) == b""
    except OSError:
        return True


class Pollers:
    """Well-behaved clients, each reading 10 input registers every 20 ms and
    logging (start time, latency, ok) for each request."""

    def __init__(self, port):
        self.port = port
        self.stop_flag = threading.Event()
        self.log = []
        self.lock = threading.Lock()
        self.threads = [threading.Thread(target=self.poll, args=(i,)) for i in range(POLLERS)]
        for t in self.threads:
            t.start()

    def poll(self, index):
        sock, tid = None, 0
        while not self.stop_flag.is_set():
            start = time.monotonic()
            ok = False
            try:
                if sock is None:
                    sock = connect(self.port, timeout=30)
                tid = (tid + 1) & 0xFFFF
                sock.sendall(mbap(tid, READ_PDU))
                reply = recv_reply(sock)
                ok = reply is not None and struct.unpack(">H", reply[:2])[0] == tid and \
                    reply[7] == 4
            except OSError:
                pass
            if not ok and sock:
                sock.close()
                sock = None
            with self.lock:
                self.log.append((start, time.monotonic() - start, ok))
            rest = POLL_PERIOD - (time.monotonic() - start)
            if rest > 0:
                time.sleep(rest)
        if sock:
            sock.close()

    def window(self, t0, t1):
        """(answered, failed, longest wait in s) for requests started in [t0, t1)."""
        with self.lock:
            rows = [r for r in self.log if t0 <= r[0] < t1]
            # A request still waiting at t1 counts with its wait so far.
        answered = sum(1 for r in rows if r[2])
        failed = sum(1 for r in rows if not r[2])
        longest = max([r[1] for r in rows] + [0.0])
        return answered, failed, longest

    def stop(self):
        self.stop_flag.set()
        for t in self.threads:
            t.join(60)


def flood(port, pid, pollers, m):
    """200 idle connections, held 1 s, then closed by us."""
    fds_before = open_fds(pid)
    t0 = time.monotonic()
    socks = []
    for _ in range(FLOOD):
        try:
            socks.append(connect(port))
        except OSError:
            pass
    time.sleep(1.0)
    closed = sum(closed_by_server(s) for s in socks)
    t1 = time.monotonic()
    answered, failed, longest = pollers.window(t0, t1)
    m["flood: connections accepted"] = len(socks)
    m["flood: idle ones closed by the server"] = closed
    m["flood: poller requests answered per s / failed"] = "%.0f / %d" % (
        answered / (t1 - t0), failed)
    m["flood: longest poller wait (ms)"] = round(longest * 1e3, 1)
    for s in socks:
        s.close()
    try:
        wait_until(lambda: open_fds(pid) <= fds_before, 5, "descriptors back")
    except TestFailure:
        pass
    m["flood: descriptors before / after"] = "%d / %d" % (fds_before, open_fds(pid))
    m["_flood"] = (len(socks), closed, failed, longest, fds_before, open_fds(pid))


def slowloris(port, pid, pollers, m):
    """64 connections each send part of a request and stall."""
    partial = mbap(7, READ_PDU)[:-2]
    t0 = time.monotonic()
    socks = []
    for _ in range(SLOWLORIS):
        try:
            s = connect(port)
            s.sendall(partial)
            socks.append(s)
        except OSError:
            pass
    closed_at = {}
    deadline = t0 + 3.0
    while time.monotonic() < deadline:
        for i, s in enumerate(socks):
            if i not in closed_at and closed_by_server(s):
                closed_at[i] = time.monotonic() - t0
        time.sleep(0.02)
    t1 = time.monotonic()
    answered, failed, longest = pollers.window(t0, t1)
    m["slowloris: stalled connections closed by the server in 3 s"] = "%d of %d" % (
        len(closed_at), len(socks))
    m["slowloris: last closed after (s)"] = (round(max(closed_at.values()), 2)
                                             if closed_at else "-")
    m["slowloris: poller requests answered / failed in 3 s"] = "%d / %d" % (answered, failed)
    m["slowloris: longest poller wait (ms)"] = round(longest * 1e3, 1)
    for s in socks:
        s.close()
    m["_slowloris"] = (len(socks), len(closed_at), failed, longest,
                       max(closed_at.values()) if closed_at else None)


def malformed(port, pollers, m):
    cases = [
        ("MBAP length 0", struct.pack(">HHHB", 1, 0, 0, 1) + READ_PDU),
        ("MBAP length 300", struct.pack(">HHHB", 2, 0, 300, 1) + READ_PDU),
        ("MBAP protocol id 1", struct.pack(">HHHB", 3, 1, 6, 1) + READ_PDU),
    ]
    t0 = time.monotonic()
    outcomes = {}
    for name, frame in cases:
        s = connect(port, timeout=1.5)
        s.sendall(frame)
        try:
            reply = recv_reply(s)
            outcome = "closed" if reply is None else "answered (%s)" % reply[7:9].hex()
        except socket.timeout:
            outcome = "no answer, left open"
        except OSError:
            outcome = "closed"
        s.close()
        outcomes[name] = outcome
        m[name] = outcome
    answered, failed, longest = pollers.window(t0, time.monotonic())
    m["malformed: poller requests failed"] = failed
    m["_malformed"] = (outcomes, failed)


def write_acl(port, m):
    """Writes from 127.0.0.2 and 127.0.0.3 (not in write_allow); their reads."""
    results = []
    for source in ("127.0.0.2", "127.0.0.3"):
        s = connect(port, source=source, timeout=3)
        check(s.getsockname()[0] == source, "bound to %s" % source)
        for tid, pdu in ((1, struct.pack(">BHH", 6, 0, 1234)),       # heartbeat register
                         (2, struct.pack(">BHH", 5, 200, 0xFF00)),   # a digital output
                         (3, struct.pack(">BHHBHH", 16, 100, 2, 4, 500, 1))):  # setpoints
            s.sendall(mbap(tid, pdu))
            reply = recv_reply(s)
            results.append(("write", reply[7:9] if reply else None))
        s.sendall(mbap(9, READ_PDU))
        reply = recv_reply(s)
        results.append(("read", reply[7:9] if reply else None))
        s.close()
    writes = [r for kind, r in results if kind == "write"]
    reads = [r for kind, r in results if kind == "read"]
    refused = sum(1 for r in writes if r and r[0] & 0x80 and r[1] == 1)
    accepted = sum(1 for r in writes if r and not r[0] & 0x80)
    m["writes from 127.0.0.2/.3: refused (01) / accepted"] = "%d / %d" % (refused, accepted)
    m["reads from 127.0.0.2/.3 answered"] = "%d of %d" % (
        sum(1 for r in reads if r and r[0] == 4), len(reads))
    m["_acl"] = (refused, len(writes), sum(1 for r in reads if r and r[0] == 4), len(reads))


def abuse(port, pid):
    """Runs every scenario against the server at 'port' (process 'pid')."""
    m = {}
    pollers = Pollers(port)
    try:
        wait_until(lambda: pollers.window(0, time.monotonic())[0] >= POLLERS * 5, 10,
                   "the pollers to be served")
        fds_start = open_fds(pid)
        flood(port, pid, pollers, m)
        slowloris(port, pid, pollers, m)
        malformed(port, pollers, m)
        write_acl(port, m)
        time.sleep(0.2)
        answered, failed, longest = pollers.window(0, time.monotonic())
    finally:
        pollers.stop()
    m["all: poller requests answered / failed"] = "%d / %d" % (answered, failed)
    m["all: active poller starved (longest wait)"] = "%s (%.0f ms)" % (
        "yes" if longest > STARVED_S else "no", longest * 1e3)
    try:
        wait_until(lambda: open_fds(pid) <= fds_start - POLLERS, 5, "descriptors back")
    except TestFailure:
        pass
    m["all: descriptors at start / at end (pollers gone)"] = "%d / %d" % (
        fds_start, open_fds(pid) + POLLERS)
    m["_all"] = (failed, longest, fds_start, open_fds(pid) + POLLERS)
    return m


def map_sizes():
    """The table sizes of jakagw's register map, for the reference."""
    sizes = {}
    for row in map_rows():
        end = int(row["address"]) + int(row["count"])
        sizes[row["table"]] = max(sizes.get(row["table"], 0), end)
    return ["--bits", str(sizes["coil"]), "--input-bits", str(sizes["discrete_input"]),
            "--registers", str(sizes["holding_register"]),
            "--input-registers", str(sizes["input_register"])]


def ref_slave_path():
    for path in (os.environ.get("REF_SLAVE"), os.path.join(BIN, "bench", "ref_slave"),
                 os.path.join(os.path.dirname(__file__), "..", "..", "build", "bench",
                              "ref_slave")):
        if path and os.access(path, os.X_OK):
            return os.path.abspath(path)
    return None


def run_reference():
    path = ref_slave_path()
    if not path:
        print("abuse: no bench/ref_slave built (make %s/bench/ref_slave): reference skipped"
              % BIN)
        return None
    port = free_port()
    proc = subprocess.Popen([path, "--port", str(port), "--max-seconds", "300"] + map_sizes(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_until(lambda: port_open(port), 10, "ref_slave to listen")
        return abuse(port, proc.pid)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=40)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def print_table(gw, ref):
    rows = [k for k in gw if not k.startswith("_")]
    width = max(len(k) for k in rows)
    print("%-*s | %-26s | %s" % (width, "abuse", "jakagw", "libmodbus reference"))
    print("-" * (width + 60))
    for k in rows:
        print("%-*s | %-26s | %s" % (width, k, gw[k], ref.get(k, "-") if ref else "-"))


def test_jakagw_under_abuse_beside_the_libmodbus_reference():
    with running((), CONFIG) as (sim, gw):
        measured = abuse(gw.modbus_port, gw.proc.pid)
    ref = run_reference()
    print_table(measured, ref)

    accepted, closed, failed, longest, before, after = measured["_flood"]
    check(accepted == FLOOD, "only %d of %d flood connections accepted" % (accepted, FLOOD))
    check(closed >= FLOOD - MAX_CLIENTS,
          "only %d idle flood connections evicted over max_clients %d" % (closed, MAX_CLIENTS))
    check(failed == 0, "%d poller requests failed during the flood" % failed)
    check(after <= before, "descriptors after the flood: %d, before %d" % (after, before))
    sent, closed, failed, longest, last = measured["_slowloris"]
    check(closed == sent, "%d of %d stalled connections still open after 3 s" % (sent - closed,
                                                                                sent))
    check(last is not None and last < FRAME_TIMEOUT_MS / 1000.0 + 1.0,
          "the last stalled connection closed after %.2f s" % (last or -1))
    check(failed == 0, "%d poller requests failed during the slowloris" % failed)
    outcomes, failed = measured["_malformed"]
    for name, outcome in outcomes.items():
        check(outcome == "closed", "%s: %s, expected the connection closed" % (name, outcome))
    check(failed == 0, "%d poller requests failed during the malformed frames" % failed)
    refused, writes, reads_ok, reads = measured["_acl"]
    check(refused == writes, "%d of %d writes from other addresses refused with 01"
          % (refused, writes))
    check(reads_ok == reads, "%d of %d reads from other addresses answered" % (reads_ok, reads))
    failed, longest, start, end = measured["_all"]
    check(failed == 0, "%d poller requests failed" % failed)
    check(longest < STARVED_S, "a poller waited %.0f ms" % (longest * 1e3))
    check(end == start, "descriptors at the end %d, at the start %d" % (end, start))


if __name__ == "__main__":
    run([test_jakagw_under_abuse_beside_the_libmodbus_reference])
