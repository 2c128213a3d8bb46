#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The shipped alert rules (docs/jakagw-alerts.yml) end to end, and the
gateway's own stall.

A real Prometheus server (Debian's prometheus) on loopback scrapes every
gateway every second and evaluates the rules every second. Each fault runs
against its own jakasim and jakagw, all at once (the alerts take tens of
seconds each; in parallel the suite takes about two minutes), with a PLC
writing the heartbeat every 200 ms as a cell's PLC does:

- silent status: jakasim keeps the status connection open and stops
  pushing (SIGUSR1);
- killed simulator: jakasim SIGKILLed, started again later on its ports;
- heartbeat stopped with the robot idle, and with a program running;
- frozen gateway: jakagw SIGSTOPped (the "up" rule), then SIGCONT (the
  gateway's stall: fault 4, not "PLC heartbeat lost");
- protective stop (SIGUSR2).

For each alert it prints the time to fire (from the fault) and to resolve
(from the recovery), measured on Prometheus' /api/v1/alerts, and fails
when one is over the bound docs/metrics.md states, or when an alert stops
firing while its fault lasts (a flapping reset).

JAKAGW_RECORD_ALERTS=1 also writes tests/prometheus/recorded-alerts-test.yml:
the series Prometheus scraped in each fault, as a promtool unit test that
expects each alert within its bound (make test replays it with promtool).
JAKAGW_ALERT_RULES=FILE runs another rules file (the "before" figures);
JAKAGW_ALERT_PATIENCE=S waits at least S s for an alert before failing.

    test_alerts.py [NAME...]   only the tests whose name contains a NAME
"""
import json
import logging
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.parse
import urllib.request

sys.path.insert(0, os.path.dirname(__file__))
from harness import (Gateway, ModbusPlc, Process, Sim, SimAt, TestFailure, check,  # noqa: E402
                     free_port, log_lines, map_rows, port_open, run, wait_until)

# The heartbeat PLC rides out a stopped gateway: pymodbus's own error
# lines for each failed connect would bury the test's output.
logging.getLogger("pymodbus").setLevel(logging.CRITICAL)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
RULES = os.environ.get("JAKAGW_ALERT_RULES", os.path.join(ROOT, "docs", "jakagw-alerts.yml"))
RECORDED = os.path.join(ROOT, "tests", "prometheus", "recorded-alerts-test.yml")
RECORD = os.environ.get("JAKAGW_RECORD_ALERTS") == "1"
PATIENCE = float(os.environ.get("JAKAGW_ALERT_PATIENCE", "0"))

ROWS = {(r["table"], r["name"]): int(r["address"]) for r in map_rows()}


def heartbeat_armed(probe):
    """Waits until the gateway has seen the PLC's heartbeat change: its age
    (input register plc_heartbeat_age_ms) reads less than a second, not
    'never' (4294967295)."""
    address = ROWS[("input_register", "plc_heartbeat_age_ms")]
    wait_until(lambda: probe.u32(address) < 1000, 10, "the PLC heartbeat seen")
IR_FAULT = ROWS[("input_register", "fault")]
IR_LOOP_STALLS = ROWS.get(("input_register", "loop_stalls"))
COIL_FAULT_RESET = ROWS[("coil", "fault_reset")]

# The bounds docs/metrics.md states for a scrape and an evaluation every
# second (status_timeout_ms and time_limit_ms at their default, 1000):
# (seconds to fire after the fault, seconds to resolve after the recovery).
BOUNDS = {
    "JakagwStatusStale": (25, 10),
    "JakagwRobotLinkDown": (45, 35),
    "JakagwPlcHeartbeatLost": (15, 5),
    "JakagwPolicyFaultLatched": (5, 5),
    "JakagwRobotStopped": (5, 5),
    "JakagwDown": (35, 5),
    "JakagwLoopStalled": (5, 65),
}

# The series the rules read: what a recording keeps.
RECORDED_SERIES = ("up", "jakagw_link_up", "jakagw_status_stale_seconds",
                   "jakagw_plc_heartbeat_age_seconds", "jakagw_policy_time_limit_seconds",
                   "jakagw_uptime_seconds", "jakagw_policy_fault", "jakagw_robot_stop",
                   "jakagw_loop_stalls_total")


class Prometheus(Process):
    """Debian's prometheus on a free loopback port, scraping 'targets'
    (host:port) as job jakagw every second with the rules file."""

    def __init__(self, targets):
        self.port = free_port()
        self.dir = tempfile.mkdtemp(prefix="jakagw-prometheus-")
        config = os.path.join(self.dir, "prometheus.yml")
        with open(config, "w") as f:
            f.write("global:\n  scrape_interval: 1s\n  scrape_timeout: 1s\n"
                    "  evaluation_interval: 1s\n"
                    "rule_files:\n  - %s\n"
                    "scrape_configs:\n  - job_name: jakagw\n    static_configs:\n"
                    "      - targets: [%s]\n" % (json.dumps(RULES),
                                                 ", ".join(json.dumps(t) for t in targets)))
        super().__init__("prometheus", [
            "prometheus", "--config.file=" + config,
            "--storage.tsdb.path=" + os.path.join(self.dir, "data"),
            "--web.listen-address=127.0.0.1:%d" % self.port, "--log.level=warn"])
        wait_until(lambda: self.ready() or not self.alive(), 60, "prometheus to start")
        check(self.alive(), "prometheus exited:\n" + self.output()[-3000:])

    def api(self, path, **params):
        url = "http://127.0.0.1:%d%s" % (self.port, path)
        if params:
            url += "?" + urllib.parse.urlencode(params)
        with urllib.request.urlopen(url, timeout=5) as r:
            body = json.loads(r.read())
        check(body.get("status") == "success", "prometheus %s: %s" % (path, body))
        return body["data"]

    def ready(self):
        try:
            with urllib.request.urlopen("http://127.0.0.1:%d/-/ready" % self.port,
                                        timeout=1) as r:
                return r.status == 200
        except OSError:
            return False

    def firing(self, instance):
        """{(alertname, frozenset(other labels)): value} firing for 'instance'."""
        out = {}
        for a in self.api("/api/v1/alerts")["alerts"]:
            labels = dict(a["labels"])
            if labels.get("instance") != instance or a["state"] != "firing":
                continue
            name = labels.pop("alertname")
            for k in ("instance", "job", "severity"):
                labels.pop(k, None)
            out[(name, frozenset(labels.items()))] = a["value"]
        return out

    def pending_or_firing(self, instance):
        return [a["labels"]["alertname"] for a in self.api("/api/v1/alerts")["alerts"]
                if a["labels"].get("instance") == instance]

    def stop(self, expect_code=0):
        try:
            return super().stop(expect_code)
        finally:
            shutil.rmtree(self.dir, True)


class HeartbeatPlc:
    """A PLC writing holding register plc_heartbeat every 200 ms from a
    thread, as a cell's PLC does; it rides out a gateway that stops
    answering (timeouts, reconnects). It owns the write side
    (single_owner), so the fault reset goes through it too."""

    def __init__(self, port):
        self.port = port
        self.lock = threading.Lock()
        self.beating = threading.Event()
        self.beating.set()
        self.done = threading.Event()
        self.client = None
        self.value = 0
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _connect(self):
        from pymodbus.client import ModbusTcpClient
        if self.client is None:
            # Whole seconds: this pymodbus takes 0.5 for no time at all.
            self.client = ModbusTcpClient("127.0.0.1", port=self.port, timeout=1, retries=0)
        return self.client.connect()  # a no-op while connected

    def _run(self):
        while not self.done.is_set():
            if self.beating.is_set():
                with self.lock:
                    try:
                        if self._connect():
                            self.value = (self.value + 1) % 65536
                            self.client.write_register(0, self.value, slave=1)
                    except Exception:  # the gateway stopped: try again later
                        self.client.close()
            self.done.wait(0.2)

    def write_coil(self, address, value):
        with self.lock:
            check(self._connect(), "PLC connect")
            rr = self.client.write_coil(address, bool(value), slave=1)
            check(not rr.isError(), "write coil %d: %s" % (address, rr))

    def input_register(self, address):
        with self.lock:
            check(self._connect(), "PLC connect")
            rr = self.client.read_input_registers(address, 1, slave=1)
            check(not rr.isError(), "read input register %d: %s" % (address, rr))
            return rr.registers[0]

    def close(self):
        self.done.set()
        self.thread.join(5)
        if self.client:
            self.client.close()


class Cell:
    """One fault's cell: jakasim, jakagw with HTTP, a heartbeat PLC."""

    def __init__(self, name, sim_args=()):
        self.name = name
        self.sims = [Sim(*sim_args)]
        self.sim_args = list(sim_args)
        self.http_port = free_port()
        self.gw = Gateway(self.sims[0], "[http]\nenabled = true\nport = %d\n" % self.http_port)
        wait_until(lambda: port_open(self.http_port), 10, "the HTTP port")
        self.instance = "127.0.0.1:%d" % self.http_port
        self.plc = HeartbeatPlc(self.gw.modbus_port)
        self.timings = []   # (alertname, labels, "fire"|"resolve", seconds)
        self.problems = []  # what went wrong, for the test's line
        self.marks = {}     # name -> wall time, for the recording
        self.expect = []    # (eval_time_name, alertname, labels or None (none firing))
        self.done = threading.Event()

    @property
    def sim(self):
        return self.sims[-1]

    def stop(self):
        self.plc.close()
        gw_out = None
        try:
            if self.gw.proc.poll() is None:
                self.gw.proc.send_signal(signal.SIGCONT)
            gw_out = self.gw.stop()
        finally:
            for s in self.sims:
                if s.proc.poll() is None:
                    s.stop()
                else:
                    os.unlink(s.log.name)
        return gw_out


def alert_key(name, **labels):
    return (name, frozenset(labels.items()))


def wait_healthy(prom, cell, seconds=10):
    """Prometheus has scraped the cell for 'seconds' with no alert pending
    or firing for it: the baseline."""
    since = [None]

    def quiet():
        alerts = prom.pending_or_firing(cell.instance)
        if alerts:
            since[0] = None
            return False
        if since[0] is None:
            since[0] = time.time()
        return time.time() - since[0] >= seconds

    wait_until(quiet, 90, "%s: a quiet baseline (alerts: %s)" % (
        cell.name, prom.pending_or_firing(cell.instance)), interval=0.5)


def wait_firing(prom, cell, keys, t_fault, must_not=()):
    """Each alert of 'keys' firing: the seconds from t_fault to each, which
    must be within its bound; none of 'must_not' may fire meanwhile."""
    left = set(keys)
    limit = max(max(BOUNDS[k[0]][0] for k in keys) + 5, PATIENCE)
    while left and time.time() - t_fault < limit:
        firing = prom.firing(cell.instance)
        now = time.time()
        for k in list(left):
            if k in firing:
                left.discard(k)
                took = now - t_fault
                cell.timings.append((k, "fire", took))
                if took > BOUNDS[k[0]][0]:
                    cell.problems.append("%s fired after %.1f s, bound %d s" %
                                         (fmt(k), took, BOUNDS[k[0]][0]))
        for name in must_not:
            if any(f[0] == name for f in firing):
                cell.problems.append("%s fired, and must not in this fault" % name)
                must_not = [m for m in must_not if m != name]
        time.sleep(0.25)
    for k in left:
        cell.problems.append("%s did not fire within %.0f s" % (fmt(k), limit))
    return not left


def hold(prom, cell, keys, until):
    """The fault goes on until 'until': every alert of 'keys' keeps firing
    (a flapping reset shows here)."""
    while time.time() < until:
        firing = prom.firing(cell.instance)
        for k in keys:
            if k not in firing:
                cell.problems.append("%s stopped firing while its fault lasted" % fmt(k))
                return False
        time.sleep(0.5)
    return True


def wait_resolved(prom, cell, keys, t_recover):
    left = set(keys)
    limit = max(BOUNDS[k[0]][1] for k in keys) + 5
    while left and time.time() - t_recover < limit:
        firing = prom.firing(cell.instance)
        now = time.time()
        for k in list(left):
            if k not in firing:
                left.discard(k)
                took = now - t_recover
                cell.timings.append((k, "resolve", took))
                if took > BOUNDS[k[0]][1]:
                    cell.problems.append("%s resolved after %.1f s, bound %d s" %
                                         (fmt(k), took, BOUNDS[k[0]][1]))
        time.sleep(0.25)
    for k in left:
        cell.problems.append("%s still firing %.0f s after the recovery" % (fmt(k), limit))


def fmt(key):
    name, labels = key
    return name + ("{%s}" % ",".join("%s=%s" % kv for kv in sorted(labels)) if labels else "")


def fault_and_recovery(prom, cell, keys, inject, recover, must_not=()):
    """The common course: baseline, fault, every alert within its bound and
    held until the longest bound has passed, recovery, every alert gone."""
    wait_healthy(prom, cell)
    cell.marks["base"] = time.time() - 8
    t_fault = time.time()
    inject()
    cell.marks["fault"] = t_fault
    wait_firing(prom, cell, keys, t_fault, must_not)
    until = t_fault + max(BOUNDS[k[0]][0] for k in keys) + 3
    hold(prom, cell, [k for k in keys if any(t[0] == k for t in cell.timings)], until)
    t_recover = time.time()
    recover()
    cell.marks["recover"] = t_recover
    fired = [k for k in keys if any(t[0] == k for t in cell.timings)]
    if fired:
        wait_resolved(prom, cell, fired, t_recover)
    cell.marks["end"] = time.time()
    for k in keys:
        cell.expect.append(("before", k[0], None))
        cell.expect.append(("bound", k[0], k))
        cell.expect.append(("resolved", k[0], None))


# ---- the faults ----

def silent_status(prom, cell):
    keys = [alert_key("JakagwStatusStale")]
    fault_and_recovery(prom, cell, keys,
                       lambda: cell.sim.proc.send_signal(signal.SIGUSR1),
                       lambda: cell.sim.proc.send_signal(signal.SIGUSR1),
                       must_not=["JakagwPolicyFaultLatched"])


def killed_simulator(prom, cell):
    keys = [alert_key("JakagwStatusStale"), alert_key("JakagwRobotLinkDown", link="status"),
            alert_key("JakagwRobotLinkDown", link="command")]

    def kill():
        cell.sim.proc.kill()
        cell.sim.proc.wait()

    def restart():
        cell.sims.append(SimAt(cell.sims[0].status_port, cell.sims[0].command_port,
                               *cell.sim_args))

    fault_and_recovery(prom, cell, keys, kill, restart)


def heartbeat_idle(prom, cell):
    keys = [alert_key("JakagwPlcHeartbeatLost")]
    fault_and_recovery(prom, cell, keys, cell.plc.beating.clear, cell.plc.beating.set,
                       must_not=["JakagwPolicyFaultLatched"])


def heartbeat_running(prom, cell):
    keys = [alert_key("JakagwPlcHeartbeatLost"), alert_key("JakagwPolicyFaultLatched")]

    def recover():
        cell.plc.beating.set()
        time.sleep(0.3)  # a heartbeat first: a reset with none is latched again
        cell.plc.write_coil(COIL_FAULT_RESET, 1)

    fault_and_recovery(prom, cell, keys, cell.plc.beating.clear, recover)
    fault = cell.plc.input_register(IR_FAULT)
    if fault != 0:
        cell.problems.append("fault register %d after the reset" % fault)


def protective_stop(prom, cell):
    keys = [alert_key("JakagwRobotStopped", kind="protective")]
    fault_and_recovery(prom, cell, keys,
                       lambda: cell.sim.proc.send_signal(signal.SIGUSR2),
                       lambda: cell.sim.proc.send_signal(signal.SIGUSR2))


def frozen_gateway(prom, cell):
    """SIGSTOP: only "up" can tell. SIGCONT: the gateway names its own
    stall (fault 4, the loop-stall alert), and the PLC's reset clears it."""
    down = [alert_key("JakagwDown")]
    fault_and_recovery(prom, cell, down, lambda: cell.gw.proc.send_signal(signal.SIGSTOP),
                       lambda: cell.gw.proc.send_signal(signal.SIGCONT))
    # Its status was stale while it could not read: no status alert for
    # that once it runs again (the rule's "for").
    must_not_after = ["JakagwStatusStale"]
    t_resume = cell.marks["recover"]
    after = [alert_key("JakagwLoopStalled"), alert_key("JakagwPolicyFaultLatched")]
    wait_firing(prom, cell, after, t_resume, must_not_after)
    hold(prom, cell, after, t_resume + 7)  # latched until the PLC resets it
    fault = cell.plc.input_register(IR_FAULT)
    if fault != 4:
        cell.problems.append("fault register %d after the stall, expected 4 (the gateway's "
                             "own stall)" % fault)
    if log_lines(cell.gw, "PLC heartbeat lost"):
        cell.problems.append("the log blames the PLC: %s" % log_lines(cell.gw,
                                                                      "PLC heartbeat lost"))
    t_reset = time.time()
    cell.plc.write_coil(COIL_FAULT_RESET, 1)
    cell.marks["reset"] = t_reset
    wait_resolved(prom, cell, [alert_key("JakagwPolicyFaultLatched")], t_reset)
    wait_resolved(prom, cell, [alert_key("JakagwLoopStalled")], t_resume)
    cell.marks["end"] = time.time()
    cell.expect.append(("resume+5", "JakagwPolicyFaultLatched", after[1]))
    cell.expect.append(("resume+5", "JakagwLoopStalled", after[0]))
    cell.expect.append(("reset+5", "JakagwPolicyFaultLatched", None))


FAULTS = [
    ("silent_status", silent_status, ()),
    ("killed_simulator", killed_simulator, ()),
    ("heartbeat_idle", heartbeat_idle, ()),
    ("heartbeat_running", heartbeat_running, ("--auto-run",)),
    ("frozen_gateway", frozen_gateway, ("--auto-run",)),
    ("protective_stop", protective_stop, ()),
]


# ---- the recording ----

def record(prom, cell):
    """The series of the cell's instance from the baseline to the end, one
    sample a second, as a promtool test case; '_' where none was scraped."""
    start = int(cell.marks["base"])
    end = int(cell.marks["end"]) + 1
    lines = ["  # %s, recorded from the real gateway: %s." % (cell.name, ", ".join(
        "%s at %ds" % (k, cell.marks[k] - start) for k in ("fault", "recover")
        if k in cell.marks)), "  - interval: 1s", "    input_series:"]
    values_at = {}
    for name in RECORDED_SERIES:
        data = prom.api("/api/v1/query_range", query='%s{instance="%s"}' % (name, cell.instance),
                        start=start, end=end, step=1)
        for series in data["result"]:
            labels = dict(series["metric"])
            labels["instance"] = "gw1"
            metric = labels.pop("__name__", name)
            by_time = {int(float(t)): v for t, v in series["values"]}
            # No value from the range query is a stale series (a missed
            # scrape alone would still show the last value): "stale" where
            # it went, so that promtool does not look back past it.
            values = []
            for t in range(start, end + 1):
                v = by_time.get(t, "_")
                values.append("stale" if v == "_" and values and values[-1] not in
                              ("_", "stale") else v)
            while values and values[-1] in ("_", "stale"):
                values.pop()
            sel = "%s{%s}" % (metric, ",".join('%s="%s"' % kv for kv in sorted(labels.items())))
            values_at[sel] = values
            lines.append("      - series: '%s'" % sel)
            lines.append("        values: '%s'" % " ".join(values))
    lines.append("    alert_rule_test:")
    rules = rule_annotations()
    # One check per (time, alert name), listing every alert of that name
    # expected to fire then.
    grouped = {}
    for when, name, key in cell.expect:
        grouped.setdefault((when, name), [])
        if key is not None and key not in grouped[(when, name)]:
            grouped[(when, name)].append(key)
    for (when, name), keys in grouped.items():
        if when == "before":
            t = cell.marks["fault"] - start - 1
        elif when == "bound":
            t = min(cell.marks["fault"] - start + BOUNDS[name][0], cell.marks["recover"] - start)
        elif when == "resolved":
            t = cell.marks["recover"] - start + BOUNDS[name][1]
        elif when == "reset+5":
            t = cell.marks["reset"] - start + BOUNDS[name][1]
        else:  # resume+5
            t = cell.marks["recover"] - start + 5
        lines.append("      - eval_time: %ds" % int(t))
        lines.append("        alertname: %s" % name)
        if not keys:
            lines.append("        exp_alerts: []")
            continue
        lines.append("        exp_alerts:")
        for key in keys:
            labels = dict(key[1], instance="gw1", job="jakagw",
                          severity=rules[name]["severity"])
            value = None
            if "$value" in json.dumps(rules[name]["annotations"]):
                # Only the fault rule shows its value: the fault then.
                value = values_at['jakagw_policy_fault{instance="gw1",job="jakagw"}'][int(t)]
            lines.append("          - exp_labels: {%s}" % ", ".join(
                "%s: %s" % kv for kv in sorted(labels.items())))
            lines.append("            exp_annotations:")
            for k, text in sorted(rules[name]["annotations"].items()):
                text = re.sub(r"\{\{ \$labels\.(\w+) \}\}", lambda m: labels[m.group(1)], text)
                text = text.replace("{{ $value }}", str(value))
                lines.append("              %s: %s" % (k, json.dumps(text)))
    return "\n".join(lines) + "\n"


def rule_annotations():
    """alertname -> {severity, annotations} from the rules file (a plain
    reader for its own layout: promtool checks the file itself)."""
    out = {}
    name = None
    with open(RULES) as f:
        for line in f:
            m = re.match(r"\s+- alert: (\w+)", line)
            if m:
                name = m.group(1)
                out[name] = {"annotations": {}}
                continue
            m = re.match(r"\s+(severity|summary|description): (.*)$", line)
            if m and name:
                value = json.loads(m.group(2)) if m.group(2).startswith('"') else m.group(2)
                if m.group(1) == "severity":
                    out[name]["severity"] = value
                else:
                    out[name]["annotations"][m.group(1)] = value
    return out


def write_recording(prom, cells):
    head = ("# SPDX-License-Identifier: MIT\n"
            "# Series scraped by a real Prometheus (every second) from the real gateway\n"
            "# in each fault, written by JAKAGW_RECORD_ALERTS=1\n"
            "# tests/integration/test_alerts.py; each case expects its alerts quiet\n"
            "# before the fault, firing within the bound docs/metrics.md states, and\n"
            "# gone within the resolve bound. promtool test rules THIS_FILE.\n"
            "rule_files:\n  - ../../docs/jakagw-alerts.yml\nevaluation_interval: 1s\ntests:\n")
    with open(RECORDED, "w") as f:
        f.write(head + "\n".join(record(prom, c) for c in cells))


# ---- the run: every fault at once, one test line each ----

RESULTS = {}


def run_all():
    if RESULTS:
        return RESULTS
    cells = []
    prom = None
    try:
        for name, _, sim_args in FAULTS:
            cells.append(Cell(name, sim_args))
        prom = Prometheus([c.instance for c in cells])
        threads = []
        for cell, (name, fn, _) in zip(cells, FAULTS):
            def body(cell=cell, fn=fn):
                try:
                    fn(prom, cell)
                except Exception as e:  # reported on the fault's own line
                    cell.problems.append("%s: %s" % (type(e).__name__, e))
                finally:
                    cell.done.set()
            t = threading.Thread(target=body, daemon=True)
            t.start()
            threads.append(t)
        for t in threads:
            t.join(300)
        if RECORD and all(not c.problems for c in cells):
            write_recording(prom, cells)
            print("wrote %s" % os.path.relpath(RECORDED, ROOT))
        for c in cells:
            RESULTS[c.name] = c
    finally:
        for c in cells:
            try:
                c.gw_final = c.stop()
            except TestFailure as e:
                c.problems.append(str(e))
        if prom:
            prom.stop(expect_code=None)
    return RESULTS


def report(name):
    cell = run_all()[name]
    for key, what, took in cell.timings:
        print("  %-44s %-7s %5.1f s" % (fmt(key), what, took))
    check(not cell.problems, "; ".join(cell.problems))


def test_silent_status_stream():
    report("silent_status")


def test_killed_simulator():
    report("killed_simulator")


def test_heartbeat_stopped_robot_idle():
    report("heartbeat_idle")


def test_heartbeat_stopped_program_running():
    report("heartbeat_running")


def test_frozen_gateway():
    report("frozen_gateway")


def test_protective_stop():
    report("protective_stop")


def test_recorded_series_replay_with_promtool():
    """The recorded faults, replayed against the rules file by promtool."""
    for path in (os.path.join(ROOT, "tests", "prometheus", "jakagw-alerts-test.yml"), RECORDED):
        r = subprocess.run(["promtool", "test", "rules", path], capture_output=True, text=True,
                           timeout=120)
        check(r.returncode == 0 and "SUCCESS" in r.stdout + r.stderr,
              "promtool test rules %s:\n%s%s" % (path, r.stdout[-3000:], r.stderr[-3000:]))


def test_stall_is_the_gateways_own_fault():
    """jakagw SIGSTOPped for 3 s (3 x time_limit_ms) with a program
    running, then SIGCONT: fault 4 (the gateway's own stall), logged once
    with its length, the program paused; never "PLC heartbeat lost"."""
    sim = Sim("--auto-run", "--log-commands")
    gw = None
    plc = None
    http_port = free_port()
    try:
        gw = Gateway(sim, "[http]\nenabled = true\nport = %d\n" % http_port)
        plc = HeartbeatPlc(gw.modbus_port)
        probe = ModbusPlc(gw.modbus_port)
        wait_until(lambda: probe.di(ROWS[("discrete_input", "status_fresh")])[0] == 1, 20,
                   "live robot data")
        heartbeat_armed(probe)
        probe.close()
        check(plc.input_register(IR_FAULT) == 0, "a fault before the stall")
        gw.proc.send_signal(signal.SIGSTOP)
        time.sleep(3)
        gw.proc.send_signal(signal.SIGCONT)
        wait_until(lambda: plc.input_register(IR_FAULT) != 0, 10, "a fault after the stall")
        fault = plc.input_register(IR_FAULT)
        stalled = log_lines(gw, "gateway loop stalled for")
        check(fault == 4, "fault %d after the stall, expected 4 (the gateway's own); log:\n%s"
              % (fault, gw.output()[-2000:]))
        check(len(stalled) == 1, "one stall line, got %s" % stalled)
        gap = int(re.search(r"stalled for (\d+) ms", stalled[0]).group(1))
        check(2900 <= gap <= 6000, "stall of %d ms logged, SIGSTOP lasted 3 s" % gap)
        check(plc.input_register(IR_LOOP_STALLS + 1) == 1, "loop_stalls register")
        check(not log_lines(gw, "PLC heartbeat lost"), "the log blames the PLC:\n" +
              "\n".join(log_lines(gw, "PLC heartbeat")))
        wait_until(lambda: "pause_program" in sim.output(), 5, "the pause sent to the robot")
        status = json.loads(http_get(http_port, "/status.json"))
        policy = status["policy"]
        check(policy["fault"] == 4 and policy["fault_name"] == "gateway loop stalled",
              "/status.json policy: %s" % policy)
        events = [e.get("text", "") for e in status.get("events", [])]
        check(any("gateway loop stalled" in t for t in events),
              "no event names the stall: %s" % events[-5:])
        print("  stall of %d ms: fault 4, pause_program sent, logged: %s" %
              (gap, re.sub(r"^<\d>", "", stalled[0])[:90]))
    finally:
        if plc:
            plc.close()
        try:
            if gw:
                gw.stop()
        finally:
            sim.stop()


def test_stall_with_the_robot_idle_is_only_reported():
    """jakagw SIGSTOPped for 1.5 s (longer than time_limit_ms and the
    status link's silence timeout) with the robot idle, its PLC beating:
    the stall is logged and counted, and that is all. The status documents
    and the heartbeat sent meanwhile wait in their sockets, and libuv runs
    its timers before it reads them: the status link's watchdog closed the
    connection for "no complete document", and the stall, judged blind,
    latched fault 4 and sent pause_program to an idle robot (every time)."""
    sim = Sim("--log-commands")
    gw = None
    plc = None
    try:
        gw = Gateway(sim, "")
        plc = HeartbeatPlc(gw.modbus_port)
        probe = ModbusPlc(gw.modbus_port)
        wait_until(lambda: probe.di(ROWS[("discrete_input", "status_fresh")])[0] == 1, 20,
                   "live robot data")
        heartbeat_armed(probe)
        probe.close()
        for _ in range(3):
            gw.proc.send_signal(signal.SIGSTOP)
            time.sleep(1.5)
            gw.proc.send_signal(signal.SIGCONT)
            time.sleep(1)
        stalled = log_lines(gw, "gateway loop stalled for")
        check(len(stalled) == 3, "three stall lines, got %s" % stalled)
        check(plc.input_register(IR_FAULT) == 0, "fault %d after stalls with the robot idle; "
              "log:\n%s" % (plc.input_register(IR_FAULT), gw.output()[-2000:]))
        check(not log_lines(gw, "no complete document"), "the status link dropped: %s"
              % log_lines(gw, "no complete document"))
        check("pause_program" not in sim.output(), "a pause sent to an idle robot")
        print("  3 stalls of 1.5 s, robot idle: logged, fault 0, status link kept")
    finally:
        if plc:
            plc.close()
        try:
            if gw:
                gw.stop()
        finally:
            sim.stop()


def http_get(port, path):
    with urllib.request.urlopen("http://127.0.0.1:%d%s" % (port, path), timeout=5) as r:
        return r.read().decode()


def metric_lines(text, name):
    return [l for l in text.splitlines() if l.startswith(name + " ") or
            l.startswith(name + "{")]


def test_never_seen_ages_have_no_sample_and_heartbeat_reads_back():
    """No robot and no heartbeat yet: the two ages have no sample (not
    4294967.295 s) while the stale streak grows from the start; a heartbeat
    written shows in /status.json's counters (it read 0 forever) and its
    age gets a sample."""
    http_port = free_port()
    gw = Gateway(None, "[http]\nenabled = true\nport = %d\n" % http_port)
    plc = None
    try:
        wait_until(lambda: port_open(http_port), 10, "the HTTP port")
        time.sleep(1.2)
        text = http_get(http_port, "/metrics")
        check("4294967" not in text, "a never-seen age exported as a number:\n%s" %
              "\n".join(l for l in text.splitlines() if "4294967" in l))
        for name in ("jakagw_status_age_seconds", "jakagw_plc_heartbeat_age_seconds"):
            check(not metric_lines(text, name), "%s has a sample: %s" %
                  (name, metric_lines(text, name)))
            check("# TYPE %s gauge" % name in text, "%s not described" % name)
        stale = float(metric_lines(text, "jakagw_status_stale_seconds")[0].split()[1])
        check(stale >= 1.0, "stale streak %.3f s with no robot for over a second" % stale)
        plc = ModbusPlc(gw.modbus_port)
        check(plc.reg(0, 1234) == 0, "heartbeat write")
        status = json.loads(http_get(http_port, "/status.json"))
        check(status["counters"]["plc_heartbeat"] == 1234,
              "counters.plc_heartbeat %s after writing 1234" % status["counters"]["plc_heartbeat"])
        check(plc.hr(0)[0] == 1234, "holding register 0 reads %d" % plc.hr(0)[0])
        ages = metric_lines(http_get(http_port, "/metrics"), "jakagw_plc_heartbeat_age_seconds")
        check(len(ages) == 1 and float(ages[0].split()[1]) < 5, "heartbeat age: %s" % ages)
        print("  no robot: no age samples, stale streak %.1f s; heartbeat 1234 reads back, "
              "%s" % (stale, ages[0]))
    finally:
        if plc:
            plc.close()
        gw.stop()


def test_stale_streak_survives_reconnects_that_bring_documents():
    """A controller that drops the status connection every 1.5 s, with
    documents flowing in between: status_fresh flaps back to 1 after every
    reconnect, the stale streak (input register 5520) runs on, as the
    alert needs."""
    sim = Sim("--drop-every-ms", "1500")
    gw = None
    plc = None
    try:
        gw = Gateway(sim, "")
        plc = ModbusPlc(gw.modbus_port)
        fresh_seen = set()
        stale_ms = 0
        documents = []
        deadline = time.monotonic() + 8
        while time.monotonic() < deadline:
            fresh_seen.add(plc.di(ROWS[("discrete_input", "status_fresh")])[0])
            stale_ms = plc.u32(ROWS[("input_register", "status_stale_ms")])
            documents.append(plc.u32(ROWS[("input_register", "documents_parsed")]))
            time.sleep(0.05)
        check(fresh_seen == {0, 1}, "status_fresh read %s: no flapping to test" % fresh_seen)
        check(documents[-1] > documents[0] + 50, "documents flowed: %s" % documents[::40])
        check(stale_ms >= 6000, "stale streak %d ms after 8 s of reconnects every 1.5 s" %
              stale_ms)
        print("  status_fresh flapped 0/1, %d documents, stale streak %d ms" %
              (documents[-1] - documents[0], stale_ms))
    finally:
        if plc:
            plc.close()
        try:
            if gw:
                gw.stop()
        finally:
            sim.stop()


TESTS = [
    test_never_seen_ages_have_no_sample_and_heartbeat_reads_back,
    test_stale_streak_survives_reconnects_that_bring_documents,
    test_stall_is_the_gateways_own_fault,
    test_stall_with_the_robot_idle_is_only_reported,
    test_silent_status_stream,
    test_killed_simulator,
    test_heartbeat_stopped_robot_idle,
    test_heartbeat_stopped_program_running,
    test_frozen_gateway,
    test_protective_stop,
    test_recorded_series_replay_with_promtool,
]

if __name__ == "__main__":
    picked = [t for t in TESTS if not sys.argv[1:] or any(a in t.__name__ for a in sys.argv[1:])]
    run(picked)
