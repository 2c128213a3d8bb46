#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""What the HTTP side costs Modbus (make bench-http).

1. The 32-client Modbus load of tests/integration/test_load.py (32 pollers
   at 1000 requests/s in total, a PLC feeding the heartbeat and sending
   commands, jakasim at 125 Hz running a program), run in alternating
   rounds against the same gateway ([http] enabled): without any HTTP
   client, and with /metrics scraped at 10 Hz over one keep-alive
   connection while the status page is open in headless Chromium (it
   fetches /status.json every second). Modbus latency p50/p99 of each
   kind, over all its rounds, and their ratio (the issue's bound: p99
   within 1.1x).
2. The CPU cost of one scrape: the gateway's utime + stime from
   /proc/PID/stat over N back-to-back scrapes of /metrics (and of
   /status.json), minus its CPU over a window of the same length with no
   HTTP client (the status stream's own cost), divided by N.

    BENCH_ROUNDS (default 3) rounds of BENCH_SECONDS (default 10) each way.
"""
import http.client
import os
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "tests", "integration"))
import test_load as load  # noqa: E402
from harness import check, free_port, raw_client, running, wait_until  # noqa: E402
from test_http import browser, close_browser  # noqa: E402

ROUNDS = int(os.environ.get("BENCH_ROUNDS", "3"))
SECONDS = float(os.environ.get("BENCH_SECONDS", "10"))
SCRAPES = int(os.environ.get("BENCH_SCRAPES", "2000"))
TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid):
    with open("/proc/%d/stat" % pid) as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime


class Scraper(threading.Thread):
    """GET /metrics every 100 ms on one keep-alive connection."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.port = port
        self.stop = threading.Event()
        self.scrapes = 0
        self.errors = 0

    def run(self):
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=5)
        next_at = time.monotonic()
        while not self.stop.is_set():
            try:
                conn.request("GET", "/metrics")
                r = conn.getresponse()
                r.read()
                self.scrapes += r.status == 200
            except (OSError, http.client.HTTPException):
                self.errors += 1
                conn.close()
                conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=5)
            next_at += 0.1
            time.sleep(max(0, next_at - time.monotonic()))
        conn.close()


def pct(values, p):
    return load.percentile(values, p) * 1e3


def scrape_cost(port, pid, path, n):
    """Gateway CPU per request of 'path', in microseconds, and the wall
    time per request seen by the client."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request("GET", path)
    size = len(conn.getresponse().read())
    c0, t0 = cpu_seconds(pid), time.monotonic()
    for _ in range(n):
        conn.request("GET", path)
        conn.getresponse().read()
    c1, t1 = cpu_seconds(pid), time.monotonic()
    conn.close()
    # The same window with no HTTP client: the status stream's own CPU.
    idle0 = cpu_seconds(pid)
    time.sleep(t1 - t0)
    idle = cpu_seconds(pid) - idle0
    return ((c1 - c0) - idle) / n * 1e6, (t1 - t0) / n * 1e6, size


def main():
    http_port = free_port()
    # A long heartbeat limit: the PLC pauses between rounds while the
    # browser starts, which is no network exception to act on here.
    config = ("[modbus]\nmax_clients = %d\n[network_exception]\ntime_limit_ms = 600000\n"
              "action = pause\nwatch = heartbeat\n[http]\nenabled = true\nport = %d\n"
              % (load.CLIENTS + 8, http_port))
    sys.setswitchinterval(0.0005)
    with running(["--period-ms", "8", "--auto-run"], config) as (sim, gw):
        probe = raw_client(gw.modbus_port)
        wait_until(lambda: load.read_ir(probe, load.I_ROBOT_HANDLE)[0] == 2, 15,
                   "the robot to accept its network-exception handler")
        probe.close()
        results = {"without HTTP": [], "with HTTP": []}
        failures = []
        scrapes = errors = 0
        for r in range(ROUNDS):
            for kind in ("without HTTP", "with HTTP") if r % 2 == 0 else ("with HTTP",
                                                                          "without HTTP"):
                driver = scraper = None
                if kind == "with HTTP":
                    driver = browser()
                    driver.get("http://127.0.0.1:%d/" % http_port)
                    wait_until(lambda: driver.find_element("id", "status-link").text ==
                               "connected", 20, "the page")
                    scraper = Scraper(http_port)
                    scraper.start()
                try:
                    lat, fail = load.load_round(gw.modbus_port, SECONDS)
                finally:
                    if scraper:
                        scraper.stop.set()
                        scraper.join(10)
                        scrapes += scraper.scrapes
                        errors += scraper.errors
                    if driver:
                        close_browser(driver)
                results[kind].extend(lat)
                failures.extend(fail)
                print("  round %d %-13s p50 %.2f ms  p99 %.2f ms  (%d requests)"
                      % (r + 1, kind, pct(sorted(lat), 50), pct(sorted(lat), 99), len(lat)),
                      flush=True)
        costs = {path: scrape_cost(http_port, gw.proc.pid, path, SCRAPES)
                 for path in ("/metrics", "/status.json")}
    base = sorted(results["without HTTP"])
    loaded = sorted(results["with HTTP"])
    print("\nModbus, 32 clients at 1000 requests/s + PLC, jakasim 125 Hz, %d x %.0f s each way:"
          % (ROUNDS, SECONDS))
    print("  %-40s p50 %6.2f ms   p99 %6.2f ms" % ("without HTTP clients", pct(base, 50),
                                                   pct(base, 99)))
    print("  %-40s p50 %6.2f ms   p99 %6.2f ms" % ("/metrics at 10 Hz + page open (Chromium)",
                                                   pct(loaded, 50), pct(loaded, 99)))
    ratio = pct(loaded, 99) / pct(base, 99)
    print("  p99 ratio %.3f (bound 1.10); %d scrapes, %d HTTP errors, %d Modbus failures"
          % (ratio, scrapes, errors, len(failures)))
    for path, (cpu_us, wall_us, size) in costs.items():
        print("  %-13s %6d bytes: gateway CPU %.0f us per request, %.0f us round trip "
              "(%d back to back)" % (path, size, cpu_us, wall_us, SCRAPES))
    check(not failures, "Modbus failures: %s" % failures[:3])


if __name__ == "__main__":
    main()
