#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Load: 32 Modbus clients poll the gateway together at 1000 requests/s in
total for LOAD_SECONDS (default 60) while jakasim pushes its status every
8 ms (125 Hz) and runs a program, and one more client acts as the PLC: it
feeds the heartbeat every 100 ms and sends commands (rapid_rate setpoints
and the clear_error trigger coil, alternately).

Passes when no request failed (no timeout, no closed connection, no
exception, no wrong transaction id), the network-exception policy never
tripped (input register 60 stays 0 and jakasim was never sent
pause_program or stop_program), and the achieved rate is at least 90 % of
the target. Prints the achieved rate and the latency percentiles, measured
around each request on its own connection.

The load generator is raw sockets, one thread per client, each with its
own schedule (client i sends at t0 + i/RATE + k * CLIENTS/RATE), so a slow
answer delays only its own client. LOAD_SECONDS, LOAD_CLIENTS and LOAD_RATE
override the defaults."""
import os
import struct
import sys
import threading
import time

from harness import check, mbap, raw_client, recv_adu, run, running, wait_until

# The full minute in CI too: make test runs this with both builds, and CI's
# whole run (packages, builds, every suite, fuzz-ci) took under 11 minutes.
SECONDS = float(os.environ.get("LOAD_SECONDS") or "60")
CLIENTS = int(os.environ.get("LOAD_CLIENTS", "32"))
RATE = float(os.environ.get("LOAD_RATE", "1000"))
TIMEOUT = 2.0  # a request unanswered this long counts as failed

I_FAULT, I_FAULTS, I_ROBOT_HANDLE = 60, 63, 64
I_EXCEPTIONS, I_EVICTIONS = 38, 42  # u32, high word first
D_STATUS_FRESH, D_COMMAND_LINK_UP = 2, 1
H_HEARTBEAT, H_RAPID_RATE, C_CLEAR_ERROR = 0, 100, 104

# What the pollers read, in turn: diagnostics, joints and TCP (floats),
# robot flags, the setpoints, the command results.
POLLS = [
    struct.pack(">BHH", 4, 0, 64),
    struct.pack(">BHH", 4, 200, 24),
    struct.pack(">BHH", 2, 16, 64),
    struct.pack(">BHH", 3, 100, 4),
    struct.pack(">BHH", 4, 4000, 72),
    struct.pack(">BHH", 1, 100, 32),
]


class Stats:
    def __init__(self):
        self.lock = threading.Lock()
        self.latencies = []
        self.failures = []
        self.requests = 0

    def add(self, latencies, failures):
        with self.lock:
            self.latencies.extend(latencies)
            self.failures.extend(failures)
            self.requests += len(latencies) + len(failures)


def request(sock, tid, pdu):
    """One request and its reply; returns the reply PDU or raises."""
    sock.sendall(mbap(tid, pdu))
    rtid, _, reply = recv_adu(sock)
    if rtid != tid:
        raise RuntimeError("transaction id %d, expected %d" % (rtid, tid))
    if reply[0] & 0x80:
        raise RuntimeError("exception %02x to function %d" % (reply[1], pdu[0]))
    return reply


def poller(port, index, t0, t_end, stats, ready):
    latencies, failures = [], []
    period = CLIENTS / RATE
    try:
        sock = raw_client(port, timeout=TIMEOUT)
    except OSError as e:
        stats.add([], ["client %d: connect: %s" % (index, e)])
        ready.release()
        return
    ready.release()
    k = 0
    tid = index * 2000
    while True:
        slot = t0 + index / RATE + k * period
        if slot >= t_end:
            break
        delay = slot - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        pdu = POLLS[(index + k) % len(POLLS)]
        tid = (tid + 1) & 0xFFFF
        start = time.perf_counter()
        try:
            request(sock, tid, pdu)
            latencies.append(time.perf_counter() - start)
        except Exception as e:  # every failure is counted, then the client reconnects
            failures.append("client %d request %d: %s: %s" % (index, k, type(e).__name__, e))
            sock.close()
            try:
                sock = raw_client(port, timeout=TIMEOUT)
            except OSError:
                break
        k += 1
    sock.close()
    stats.add(latencies, failures)


def plc(port, t_end, stats, faults, commands):
    """Heartbeat every 100 ms, a command with every beat, the fault read."""
    latencies, failures = [], []
    sock = raw_client(port, timeout=TIMEOUT)
    beat, tid, k = 0, 0, 0
    next_at = time.monotonic()
    while next_at < t_end:
        delay = next_at - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        next_at += 0.1
        beat = (beat + 1) & 0xFFFF
        if k % 2 == 0:
            command = struct.pack(">BHH", 6, H_RAPID_RATE, 500 if k % 4 == 0 else 800)
        else:  # the trigger coil: 0 -> 1 sends clear_error, then back to 0
            command = struct.pack(">BHH", 5, C_CLEAR_ERROR, 0xFF00 if k % 4 == 1 else 0)
        k += 1
        for pdu in (struct.pack(">BHH", 6, H_HEARTBEAT, beat), command,
                    struct.pack(">BHH", 4, I_FAULT, 1)):
            tid = (tid + 1) & 0xFFFF
            start = time.perf_counter()
            try:
                reply = request(sock, tid, pdu)
                latencies.append(time.perf_counter() - start)
                if pdu[0] == 4:
                    faults.append(struct.unpack(">H", reply[2:4])[0])
                elif pdu is command:
                    commands[0] += 1
            except Exception as e:
                failures.append("PLC: %s: %s" % (type(e).__name__, e))
                sock.close()
                sock = raw_client(port, timeout=TIMEOUT)
    sock.close()
    stats.add(latencies, failures)


def percentile(sorted_values, p):
    if not sorted_values:
        return float("nan")
    return sorted_values[min(len(sorted_values) - 1, int(p / 100.0 * len(sorted_values)))]


def load_round(port, seconds, start=None):
    """One run of the load from 'start' (time.time(); default: 0.5 s from
    now) for 'seconds', for the benchmarks that set it beside something
    else: the sorted latencies (s) and the failures."""
    stats = Stats()
    faults, commands = [], [0]
    ready = threading.Semaphore(0)
    t0 = time.monotonic() + (start - time.time() if start else 0.5)
    t_end = t0 + seconds
    threads = [threading.Thread(target=poller, args=(port, i, t0, t_end, stats, ready))
               for i in range(CLIENTS)]
    threads.append(threading.Thread(target=plc, args=(port, t_end, stats, faults, commands)))
    for t in threads:
        t.start()
    for _ in range(CLIENTS):
        ready.acquire()
    for t in threads:
        t.join(seconds + 30)
    return stats.latencies, stats.failures


def read_ir(sock, address, count=1):
    reply = request(sock, 1, struct.pack(">BHH", 4, address, count))
    return list(struct.unpack(">%dH" % count, reply[2:]))


def read_u32(sock, address):
    hi, lo = read_ir(sock, address, 2)
    return hi << 16 | lo


def test_32_clients_at_1000_requests_per_second_with_commands_and_heartbeat():
    config = ("[modbus]\nmax_clients = %d\n[network_exception]\ntime_limit_ms = 1000\n"
              "action = pause\nwatch = heartbeat\n" % (CLIENTS + 8))
    with running(["--period-ms", "8", "--auto-run", "--log-commands"], config) as (sim, gw):
        probe = raw_client(gw.modbus_port)
        wait_until(lambda: request(probe, 1, struct.pack(">BHH", 2, 0, 3))[2] & 0b110 == 0b110,
                   10, "fresh status and the command link")
        wait_until(lambda: read_ir(probe, I_ROBOT_HANDLE)[0] == 2, 10,
                   "the robot to accept its network-exception handler")
        probe.close()  # silent through the run, the idle timeout would close it
        sys.setswitchinterval(0.0005)  # let a woken client run at once
        stats = Stats()
        faults, commands = [], [0]
        ready = threading.Semaphore(0)
        t0 = time.monotonic() + 1.0
        t_end = t0 + SECONDS
        threads = [threading.Thread(target=poller, args=(gw.modbus_port, i, t0, t_end, stats, ready))
                   for i in range(CLIENTS)]
        threads.append(threading.Thread(target=plc, args=(gw.modbus_port, t_end, stats, faults,
                                                          commands)))
        for t in threads:
            t.start()
        for _ in range(CLIENTS):
            ready.acquire()
        for t in threads:
            t.join(SECONDS + 30)
        elapsed = time.monotonic() - t0
        check(not any(t.is_alive() for t in threads), "load clients still running")
        probe = raw_client(gw.modbus_port)
        fault_now, faults_total = read_ir(probe, I_FAULT, 4)[0], read_ir(probe, I_FAULTS)[0]
        evictions = read_u32(probe, I_EVICTIONS)
        exceptions = read_u32(probe, I_EXCEPTIONS)
        probe.close()
        sim_log = sim.output()

    lat = sorted(stats.latencies)
    achieved = stats.requests / elapsed
    if SECONDS < 60:
        print("load: a %.0f s run (LOAD_SECONDS=60 for the full minute)" % SECONDS)
    print("load: %d clients + 1 PLC, %.0f s: %d requests, %.0f requests/s (target %.0f + 30 "
          "from the PLC), %d failed; latency p50 %.2f ms, p99 %.2f ms, max %.2f ms; "
          "%d commands; status at 125 Hz"
          % (CLIENTS, elapsed, stats.requests, achieved, RATE, len(stats.failures),
             percentile(lat, 50) * 1e3, percentile(lat, 99) * 1e3,
             (lat[-1] if lat else float("nan")) * 1e3, commands[0]), flush=True)
    for f in stats.failures[:10]:
        print("  " + f)
    check(not stats.failures, "%d requests failed, first: %s" % (len(stats.failures),
                                                                stats.failures[0]
                                                                if stats.failures else ""))
    check(achieved >= 0.9 * RATE, "achieved %.0f requests/s of %.0f" % (achieved, RATE))
    check(faults and max(faults) == 0 and fault_now == 0 and faults_total == 0,
          "the network-exception fault latched under load (fault register %s, %d faults)"
          % (sorted(set(faults)), faults_total))
    paused = [line for line in sim_log.splitlines()
              if "jakasim: command" in line and ("pause_program" in line.split("->")[0] or
                                                 "stop_program" in line.split("->")[0])]
    check(not paused, "the robot was sent: %s" % paused[:3])
    sent = [line.split("->")[0] for line in sim_log.splitlines() if "jakasim: command" in line]
    rapid = sum('"rapid_rate"' in line for line in sent)
    cleared = sum('"clear_error"' in line for line in sent)
    check(rapid >= commands[0] // 2 - 1 and cleared >= commands[0] // 4 - 1,
          "the robot got %d rapid_rate and %d clear_error of %d command writes"
          % (rapid, cleared, commands[0]))
    check(evictions == 0, "%d clients evicted" % evictions)
    check(exceptions == 0, "the gateway counted %d exception replies" % exceptions)
    check(commands[0] >= int(SECONDS * 10 * 0.9), "only %d commands sent" % commands[0])


if __name__ == "__main__":
    run([test_32_clients_at_1000_requests_per_second_with_commands_and_heartbeat])
