#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""What /status.json?registers=1 fetched back to back costs Modbus
(make bench-http-registers).

The review's load (issue 30): HTTP_CLIENTS (default 16) local processes,
each fetching /status.json?registers=1 (about 87 KB) back to back on its
own keep-alive connection, while the 32-client Modbus load of
tests/integration/test_load.py runs (32 pollers at 1000 requests/s in
total, a PLC feeding the heartbeat and sending commands, jakasim at 125 Hz
running a program). Rounds alternate, against the same gateway, between
no HTTP client ("idle") and the fetchers ("loaded"). Prints the Modbus
p50/p99 of each kind over all its rounds and their ratio (the issue's
bound: p99 within 1.5x), and the fetches' median and p99 round trip (the
bound: median <= 1.5 ms on loopback).

The fetchers are separate processes, so that their Python does not share
a lock with the Modbus clients' timing.

A third kind of round, "control", runs the same fetchers against a second
gateway (its own jakasim) while the load runs against the first: what the
fetchers' own CPU costs the Modbus clients on this machine, which no
gateway can remove. On a 2-core machine, 16 Python processes each parsing
90 KB answers back to back compete with the Modbus clients' Python for
the cores.

    BENCH_ROUNDS (default 2) rounds of BENCH_SECONDS (default 8) each kind.
"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "integration"))
import test_load as load  # noqa: E402
from harness import check, free_port, raw_client, running, wait_until  # noqa: E402

ROUNDS = int(os.environ.get("BENCH_ROUNDS", "2"))
SECONDS = float(os.environ.get("BENCH_SECONDS", "8"))
HTTP_CLIENTS = int(os.environ.get("HTTP_CLIENTS", "16"))
PATH = "/status.json?registers=1"

# One fetcher: back to back until its deadline, then its round trips (s)
# and the size of the last answer as one JSON line on stdout.
FETCHER = r"""
import http.client, json, sys, time
port, t_start, t_end, path = int(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
times, errors, size = [], 0, 0
time.sleep(max(0, t_start - time.time()))
while time.time() < t_end:
    t0 = time.perf_counter()
    try:
        conn.request("GET", path)
        r = conn.getresponse()
        body = r.read()
        if r.status != 200:
            raise OSError("HTTP %d" % r.status)
        times.append(time.perf_counter() - t0)
        size = len(body)
    except (OSError, http.client.HTTPException):
        errors += 1
        conn.close()
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
print(json.dumps({"times": times, "errors": errors, "size": size}))
"""


def fetchers(http_port, start, seconds):
    """Starts the fetchers for a round of 'seconds' from 'start' (time.time()):
    started early, so that 16 Pythons starting up are not in the round."""
    return [subprocess.Popen([sys.executable, "-c", FETCHER, str(http_port), str(start),
                              str(start + seconds), PATH],
                             stdout=subprocess.PIPE, text=True)
            for _ in range(HTTP_CLIENTS)]


def collect(procs):
    times, errors, size = [], 0, 0
    for p in procs:
        out, _ = p.communicate(timeout=60)
        r = json.loads(out)
        times.extend(r["times"])
        errors += r["errors"]
        size = max(size, r["size"])
    return times, errors, size


def pct(values, p):
    return load.percentile(values, p) * 1e3


def main():
    http_port = free_port()
    config = ("[modbus]\nmax_clients = %d\n[network_exception]\ntime_limit_ms = 600000\n"
              "action = pause\nwatch = heartbeat\n[http]\nenabled = true\nport = %d\n"
              % (load.CLIENTS + 8, http_port))
    sys.setswitchinterval(0.0005)
    results = {"idle": [], "loaded": [], "control": []}
    control_port = free_port()
    fetch_times, fetch_errors, size, failures = [], 0, 0, []
    control_config = "[http]\nenabled = true\nport = %d\n" % control_port
    with running(["--period-ms", "8", "--auto-run"], config) as (sim, gw), \
            running(["--period-ms", "8", "--auto-run"], control_config):
        probe = raw_client(gw.modbus_port)
        wait_until(lambda: load.read_ir(probe, load.I_ROBOT_HANDLE)[0] == 2, 15,
                   "the robot to accept its network-exception handler")
        probe.close()
        for r in range(ROUNDS):
            for kind in ("idle", "loaded", "control") if r % 2 == 0 else ("control", "loaded",
                                                                          "idle"):
                start = time.time() + 3
                target = {"loaded": http_port, "control": control_port}.get(kind)
                procs = fetchers(target, start, SECONDS) if target else []
                lat, fail = load.load_round(gw.modbus_port, SECONDS, start)
                if procs:
                    t, e, n = collect(procs)
                    if kind == "loaded":
                        fetch_times.extend(t)
                        fetch_errors += e
                        size = n
                results[kind].extend(lat)
                failures.extend(fail)
                print("  round %d %-7s Modbus p50 %.2f ms  p99 %.2f ms  (%d requests)"
                      % (r + 1, kind, pct(sorted(lat), 50), pct(sorted(lat), 99), len(lat)),
                      flush=True)
    idle, loaded, fetch = sorted(results["idle"]), sorted(results["loaded"]), sorted(fetch_times)
    control = sorted(results["control"])
    print("\nModbus, 32 clients at 1000 requests/s + PLC, jakasim 125 Hz, %d x %.0f s each way:"
          % (ROUNDS, SECONDS))
    print("  %-46s p50 %6.2f ms   p99 %6.2f ms" % ("idle (no HTTP client)", pct(idle, 50),
                                                   pct(idle, 99)))
    print("  %-46s p50 %6.2f ms   p99 %6.2f ms"
          % ("%d clients fetching %s" % (HTTP_CLIENTS, PATH), pct(loaded, 50), pct(loaded, 99)))
    print("  %-46s p50 %6.2f ms   p99 %6.2f ms"
          % ("control: the same fetchers at another gateway", pct(control, 50),
             pct(control, 99)))
    print("  Modbus p99 ratio loaded/idle %.2f (bound 1.50), p50 ratio %.2f; "
          "loaded/control p99 %.2f, p50 %.2f"
          % (pct(loaded, 99) / pct(idle, 99), pct(loaded, 50) / pct(idle, 50),
             pct(loaded, 99) / pct(control, 99), pct(loaded, 50) / pct(control, 50)))
    print("  %s (%d bytes): %d fetches (%.0f/s), round trip median %.2f ms, p99 %.2f ms "
          "(bound: median 1.50 ms); %d HTTP errors, %d Modbus failures"
          % (PATH, size, len(fetch), len(fetch) / (ROUNDS * SECONDS), pct(fetch, 50),
             pct(fetch, 99), fetch_errors, len(failures)))
    check(not failures, "Modbus failures: %s" % failures[:3])


if __name__ == "__main__":
    main()
