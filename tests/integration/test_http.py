#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The HTTP side ([http] enabled): Prometheus metrics, /status.json, the
status page in a real browser, the audit trail, and what hostile HTTP
clients can do to the gateway (nothing to Modbus).

Real clients throughout: the real jakasim and jakagw, pymodbus as the PLC,
Debian's promtool on /metrics and on the alert rules, headless Chromium
driven by selenium for the page, raw sockets for the abuse.

    test_http.py [NAME...]   only the tests whose name contains a NAME
"""
import http.client
import json
import os
import re
import shutil
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time

import contextlib

from harness import (JAKAGW, Gateway, ModbusPlc, Sim, TestFailure, check, free_port,
                     log_lines, map_rows, port_open, raw_client, read_input_registers, run,
                     wait_until)

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
ALERTS = os.path.join(ROOT, "docs", "jakagw-alerts.yml")
ALERTS_TEST = os.path.join(ROOT, "tests", "prometheus", "jakagw-alerts-test.yml")

ROWS = {(r["table"], r["name"]): int(r["address"]) for r in map_rows()}
IR = {name: addr for (table, name), addr in ROWS.items() if table == "input_register"}
COIL = {name: addr for (table, name), addr in ROWS.items() if table == "coil"}
DI = {name: addr for (table, name), addr in ROWS.items() if table == "discrete_input"}
RESULT_STATE = IR["power_on_state"] if "power_on_state" in IR else None

FIXED_NAMES = ("jakagw_link_up", "jakagw_status_age_seconds", "jakagw_modbus_requests_total",
               "jakagw_commands_total", "jakagw_policy_fault")


def http_config(port, extra=""):
    return "[http]\nenabled = true\nport = %d\n%s" % (port, extra)


class Http:
    """A gateway's HTTP endpoint."""

    def __init__(self, port):
        self.port = port

    def get(self, path, method="GET", headers=None, timeout=10):
        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        try:
            conn.request(method, path, headers=headers or {})
            r = conn.getresponse()
            return r.status, dict(r.getheaders()), r.read()
        finally:
            conn.close()

    def metrics(self):
        status, headers, body = self.get("/metrics")
        check(status == 200, "/metrics answered %d" % status)
        return body.decode()

    def status(self, registers=False):
        status, headers, body = self.get("/status.json" + ("?registers=1" if registers else ""))
        check(status == 200 and headers.get("Content-Type") == "application/json",
              "/status.json answered %d %s" % (status, headers))
        return json.loads(body)


def parse_metrics(text):
    """{(name, frozenset(labels.items())): value} of the text format."""
    out = {}
    for line in text.splitlines():
        if not line or line.startswith("#"):
            continue
        m = re.match(r'^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{(.*)\})? (\S+)$', line)
        check(m, "not a sample line: %r" % line)
        labels = dict(re.findall(r'(\w+)="((?:[^"\\]|\\.)*)"', m.group(3) or ""))
        out[(m.group(1), frozenset(labels.items()))] = float(m.group(4))
    return out


def metric(samples, name, **labels):
    return samples[(name, frozenset(labels.items()))]


def metric_sum(samples, name):
    return sum(v for (n, _), v in samples.items() if n == name)


def promtool(*args, stdin=None):
    return subprocess.run(["promtool"] + list(args), input=stdin, capture_output=True,
                          text=True, timeout=60)


def u32(regs):
    return regs[0] << 16 | regs[1]


@contextlib.contextmanager
def running(sim_args=(), config=""):
    """harness.running, keeping the gateway's log after it stopped
    (gw.final_output) and waiting for the robot's data to be live."""
    sim = Sim(*sim_args)
    gw = None
    try:
        gw = Gateway(sim, config)
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: plc.di(DI["status_fresh"])[0] == 1 and
                   plc.di(DI["command_link_up"])[0] == 1, 20, "live robot data")
        plc.close()
        yield sim, gw
    finally:
        try:
            if gw:
                gw.final_output = gw.stop()
        finally:
            sim.stop()


def wait_http(port, gw):
    """The HTTP port listening; if not, the gateway's log says why."""
    try:
        wait_until(lambda: port_open(port), 10, "the HTTP port %d" % port)
    except TestFailure:
        raise TestFailure("no HTTP on port %d; jakagw's log:\n%s" % (port, gw.output()[-3000:]))


def gateway_with_http(sim_args=(), extra_config=""):
    port = free_port()
    return port, running(list(sim_args), http_config(port, extra_config))


def audit_lines(gw):
    """The audit records on stderr, as dicts of their key=value fields."""
    out = []
    text = gw.final_output if hasattr(gw, "final_output") else gw.output()
    for line in [l for l in text.splitlines() if "audit: command=" in l]:
        rest = line.split("audit: ", 1)[1]
        fields = dict(re.findall(r'(\w+)=("(?:[^"]*)"|\S*)', rest.split(" error_msg=")[0]))
        fields = {k: v.strip('"') for k, v in fields.items()}
        fields["error_msg"] = rest.split(" error_msg=", 1)[1] if " error_msg=" in rest else ""
        out.append(fields)
    return out


# ---- metrics ----

def test_metrics_pass_promtool_and_carry_the_fixed_names():
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        plc.ir(0, 10)
        text = web.metrics()
        r = promtool("check", "metrics", stdin=text)
        check(r.returncode == 0 and not r.stdout.strip() and not r.stderr.strip(),
              "promtool check metrics: rc %d\n%s%s" % (r.returncode, r.stdout, r.stderr))
        samples = parse_metrics(text)
        for name in FIXED_NAMES:
            check(any(n == name for n, _ in samples) or "# TYPE %s " % name in text,
                  "no metric %s" % name)
        check(metric(samples, "jakagw_link_up", link="status") == 1 and
              metric(samples, "jakagw_link_up", link="command") == 1, "links up")
        check(0 <= metric(samples, "jakagw_status_age_seconds") < 2, "status age")
        check(metric(samples, "jakagw_policy_fault") == 0, "no fault")
        check(metric(samples, "jakagw_commands_total", command="set_network_exception_handle",
                     result="done") == 1, "the handler command counted")
        status, headers, body = web.get("/metrics", method="HEAD")
        check(status == 200 and body == b"", "HEAD /metrics: %d, %d bytes" % (status, len(body)))
        plc.close()
        print("  %d samples, %d bytes, promtool clean" % (len(samples), len(text)))


def test_values_follow_modbus_and_equal_the_diagnostics_registers():
    """Every value is the one the diagnostics registers show: read the
    registers, scrape, compare; then Modbus traffic moves both."""
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        fc4 = parse_metrics(web.metrics()).get(
            ("jakagw_modbus_requests_total",
             frozenset({"transport": "modbus", "function": "4"}.items())), 0)
        for k in range(5):
            # One read: the registers as they stood before it was counted.
            regs = plc.ir(0, 60)
            samples = parse_metrics(web.metrics())
            requests = u32(regs[IR["modbus_requests"]:])
            check(metric_sum(samples, "jakagw_modbus_requests_total") == requests + 1,
                  "requests: metrics %s, register %d (+1 for the read itself)"
                  % (metric_sum(samples, "jakagw_modbus_requests_total"), requests))
            # Two reads of function 4 per turn: this one, and the refused one below.
            check(metric(samples, "jakagw_modbus_requests_total", transport="modbus",
                         function="4") == fc4 + 2 * k + 1, "function 4 counted")
            check(metric_sum(samples, "jakagw_modbus_exceptions_total") ==
                  u32(regs[IR["modbus_exceptions"]:]), "exceptions")
            check(metric_sum(samples, "jakagw_modbus_clients") == regs[IR["modbus_clients"]] == 1,
                  "clients")
            docs = u32(regs[IR["documents_parsed"]:])
            check(docs <= metric(samples, "jakagw_documents_parsed_total") <= docs + 20,
                  "documents parsed: register %d, metric %s" % (
                      docs, metric(samples, "jakagw_documents_parsed_total")))
            check(metric(samples, "jakagw_modbus_request_duration_seconds_count") == requests + 1,
                  "the histogram counts every request")
            # Exceptions move both: a read past the table.
            rr = plc.client.read_input_registers(65000, 1, slave=1)
            check(rr.isError(), "the read past the table is refused")
        after = parse_metrics(web.metrics())
        regs = plc.ir(0, 60)
        check(metric_sum(after, "jakagw_modbus_exceptions_total") ==
              u32(regs[IR["modbus_exceptions"]:]) == 5, "5 exceptions in both")
        check(metric(after, "jakagw_modbus_exceptions_total", transport="modbus", code="02") == 5,
              "exception 02 by code")
        # The heartbeat's age: the register and the gauge agree.
        check(plc.reg(0, 1) == 0, "heartbeat write")
        age_reg = u32(plc.ir(IR["plc_heartbeat_age_ms"], 2))
        age = metric(parse_metrics(web.metrics()), "jakagw_plc_heartbeat_age_seconds")
        check(age_reg / 1000 <= age < age_reg / 1000 + 1, "heartbeat age %s vs %d ms"
              % (age, age_reg))
        plc.close()


def test_status_json_clients_policy_and_counters():
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        check(plc.reg(0, 7) == 0, "heartbeat write")
        regs = plc.ir(0, 60)
        doc = web.status()
        check(doc["links"]["status"]["up"] and doc["links"]["command"]["up"], "links up")
        check(doc["status_fresh"] and doc["status_age_ms"] < 2000, "fresh status")
        check(doc["robot"]["controller_version"], "controller version shown")
        check(len(doc["clients"]) == 1, "one client: %r" % doc["clients"])
        c = doc["clients"][0]
        check(c["address"] == "127.0.0.1" and c["transport"] == "modbus" and c["owner"] and
              c["requests"] == 2 and c["exceptions"] == 0 and c["last_request_age_ms"] < 5000,
              "client %r" % c)
        check(doc["policy"]["write_owner"] == "127.0.0.1:%d" % plc.client.socket.getsockname()[1]
              and doc["policy"]["fault"] == 0 and
              doc["policy"]["handler"] == "accepted", "policy %r" % doc["policy"])
        check(doc["counters"]["modbus_requests"] == u32(regs[IR["modbus_requests"]:]) + 1,
              "counters as the registers")
        full = web.status(registers=True)
        by_name = {(e[0], e[2]): e for e in full["registers"]}
        check(by_name[(2, "map_magic")][3] == 0x4A4B and by_name[(2, "map_magic")][1] == 0,
              "the register map with values: %r" % (by_name.get((2, "map_magic")),))
        check(by_name[(3, "plc_heartbeat")][3] == 7, "the heartbeat register's value")
        plc.close()


def test_markup_from_the_robot_stays_text_in_json_and_audit():
    message = '<img src=x onerror="alert(1)"><script>alert(2)</script>&amp;\u2028'
    # Bytes that are no UTF-8 after it: /status.json stays UTF-8 (U+FFFD).
    raw = message.encode() + b"\xff\xc3"
    port, ctx = gateway_with_http(["--fail-command", "power_on", "--fail-message",
                                   raw.decode("utf-8", "surrogateescape")])
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: web.status()["policy"]["handler"] == "accepted", 15, "the handler")
        check(plc.pulse(COIL["cmd_power_on"]) == 0, "power_on write")
        wait_until(lambda: any(c["command"] == "power_on" for c in web.status()["commands"]), 10,
                   "power_on in the last commands")
        status, headers, body = web.get("/status.json")
        check(b"<" not in body and b">" not in body and b"&" not in body and
              b"\xe2\x80\xa8" not in body, "raw markup or U+2028 in /status.json")
        try:
            doc = json.loads(body.decode("utf-8"))
        except ValueError as e:
            raise TestFailure("/status.json is not UTF-8 JSON: %s" % e)
        rec = [c for c in doc["commands"] if c["command"] == "power_on"][0]
        check(rec["error_msg"] == message + "\ufffd\ufffd" and rec["result"] == "robot error" and
              rec["error_code"] == 2 and re.match(r"^127\.0\.0\.1:\d+$", rec["client"]) and
              rec["transport"] == "modbus", "record %r" % rec)
        samples = parse_metrics(web.metrics())
        check(metric(samples, "jakagw_commands_total", command="power_on",
                     result="robot_error") == 1, "the failure counted")
        plc.close()


# ---- audit trail ----

def test_audit_records_commands_refusals_and_aggregates_outputs():
    port, ctx = gateway_with_http(["--log-commands"])
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: web.status()["policy"]["handler"] == "accepted", 15, "the handler")
        check(plc.pulse(COIL["cmd_power_on"]) == 0, "power_on")
        wait_until(lambda: [a for a in audit_lines(gw) if a["command"] == "power_on"], 10,
                   "power_on's audit line")
        # Motion is off: a refused write, recorded with who and why.
        check(plc.coil(COIL["cmd_shutdown"], 1) == 1, "shutdown refused with 01")
        # 40 output writes: one line at once, the rest counted. Each a
        # change (1 first: a 0 the robot reports already sends nothing).
        for i in range(40):
            check(plc.coil(COIL["cabinet_do_1"], (i + 1) % 2) == 0, "output write %d" % i)
        wait_until(lambda: len(sim_sent(sim, "set_digital_output")) >= 40, 10, "40 outputs sent")
        wait_until(lambda: sum(1 for c in web.status()["commands"]
                               if c["command"] == "set_digital_output") >= 1, 10,
                   "the first output record")
        lines = audit_lines(gw)
        outputs = [a for a in lines if a["command"] == "set_digital_output"]
        check(len(outputs) == 1 and outputs[0]["count"] == "1",
              "outputs not aggregated: %d lines %r" % (len(outputs), outputs[:3]))
        plc.close()
    out = audit_lines(gw)
    power = [a for a in out if a["command"] == "power_on"]
    check(len(power) == 1 and power[0]["result"] == "done" and power[0]["transport"] == "modbus"
          and re.match(r"^127\.0\.0\.1:\d+$", power[0]["client"]),
          "power_on recorded once: %r" % power)
    refused = [a for a in out if a["command"] == "write"]
    # Where and why, in the words of the result registers.
    check(len(refused) == 1 and refused[0]["result"] == "refused" and
          refused[0]["what"] == "coil %d shutdown" % COIL["cmd_shutdown"] and
          refused[0]["reason"].startswith("shutdown off") and
          refused[0]["error_code"] == "1", "refusal recorded: %r" % refused)
    outputs = [a for a in out if a["command"] == "set_digital_output"]
    total = sum(int(a["count"]) for a in outputs)
    check(total == 40 and len(outputs) == 2, "outputs: %d records for %d commands: %r"
          % (len(outputs), total, outputs))
    # The values written: the first's, then the group's distinct ones (a
    # quote in a field is \x22 on the line).
    whats = [o["what"].replace("\\x22", '"') for o in outputs]
    check('"value":1' in whats[0] and '"value":1' in whats[1] and '"value":0' in whats[1],
          "output values %r" % whats)
    handler = [a for a in out if a["command"] == "set_network_exception_handle"]
    check(handler and handler[0]["transport"] == "gateway", "the gateway's own command")
    print("  power_on: %s; refusal: %s; 40 outputs in %d records"
          % (power[0]["result"], refused[0]["what"], len(outputs)))


def test_writes_refused_by_the_map_are_audited():
    """A write the map refuses before it is judged (an address outside the
    map: 02) is a refused write like any other: recorded once, with who."""
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        rr = plc.client.write_coil(65000, True, slave=1)
        check(rr.isError() and rr.exception_code == 2, "coil 65000: %s" % rr)
        check(plc.ir(0)[0] == 0x4A4B, "still answering")
        wait_until(lambda: any(c["command"] == "write" for c in web.status()["commands"]), 10,
                   "the refusal in the last commands")
        rec = [c for c in web.status()["commands"] if c["command"] == "write"]
        check(len(rec) == 1 and rec[0]["what"] == "coil 65000" and rec[0]["error_code"] == 2 and
              rec[0]["reason"] == "no such address in the register map" and
              re.match(r"^127\.0\.0\.1:\d+$", rec[0]["client"]) and
              rec[0]["transport"] == "modbus", "record %r" % rec)
        samples = parse_metrics(web.metrics())
        check(metric(samples, "jakagw_writes_refused_total", code="02") == 1, "counted as 02")
        plc.close()
    lines = [a for a in audit_lines(gw) if a["command"] == "write"]
    check(len(lines) == 1 and lines[0]["what"] == "coil 65000" and lines[0]["error_code"] == "2",
          "audit lines %r" % lines)


def test_mbaps_clients_are_audited_with_certificate_and_role():
    """On Modbus/TCP Security, who is the certificate: its subject and role
    are in the audit records, /status.json and the transport's metrics."""
    import test_tls as tls  # makes the test PKI (tests/tls/make-pki.sh)
    port = free_port()
    with tls.Mbaps("[http]\nenabled = true\nport = %d\n" % port) as m:
        web = Http(port)
        wait_http(port, m.gw)
        wait_until(lambda: web.status()["policy"]["handler"] == "accepted", 15, "the handler")
        op = tls.TlsPlc(m.tls_port, "operator")
        check(op.coil(COIL["cabinet_do_1"], 1) == 0, "operator sets an output")
        mon = tls.TlsPlc(m.tls_port, "monitor")
        check(mon.coil(COIL["cabinet_do_1"], 0) == 1, "monitor may not write: 01")
        wait_until(lambda: len(web.status()["commands"]) >= 2, 10, "the records")
        doc = web.status()
        clients = {c["role"]: c for c in doc["clients"]}
        check(set(clients) == {"operator", "monitor"} and
              all(c["transport"] == "mbaps" and "CN=" in c["subject"] for c in clients.values()),
              "clients %r" % doc["clients"])
        out = {c["command"]: c for c in doc["commands"]}
        check(out["set_digital_output"]["role"] == "operator" and
              out["set_digital_output"]["transport"] == "mbaps" and
              "CN=" in out["set_digital_output"]["subject"] and
              out["set_digital_output"]["result"] == "done", "output record %r" % out)
        check(out["write"]["role"] == "monitor" and out["write"]["result"] == "refused" and
              out["write"]["what"] == "coil %d" % COIL["cabinet_do_1"] and
              out["write"]["reason"] == 'outside role "monitor"', "refusal %r" % out)
        samples = parse_metrics(web.metrics())
        check(metric(samples, "jakagw_modbus_clients", transport="mbaps") == 2 and
              metric(samples, "jakagw_modbus_requests_total", transport="mbaps",
                     function="5") == 2 and
              metric(samples, "jakagw_modbus_exceptions_total", transport="mbaps",
                     code="01") == 1, "mbaps metrics")
        op.close()
        mon.close()
        lines = [l for l in m.gw.output().splitlines() if "audit: command=write" in l]
        check(len(lines) == 1 and 'role="monitor"' in lines[0] and "transport=mbaps" in lines[0],
              "the refusal's line: %r" % lines)
        print("  %s" % lines[0])


def test_rtu_line_is_transport_rtu_in_metrics_status_and_audit():
    """The RTU line is a client of its own transport: jakagw_modbus_clients
    {transport="rtu"} (beside the TCP client, not counted as one), its
    requests under transport="rtu", its entry in /status.json's clients and
    its commands in the audit trail, named by its device (a path with
    markup in it, kept as text). The master's write sent again at once (a
    retry after a spoiled reply) is answered again, not acted on again, and
    a frame in an exception's form for this unit is skipped: each counted
    in jakagw_rtu_frames_total (kind "repeat", "exception") and in its
    input register."""
    import test_rtu as rtu
    line = rtu.SerialPair()
    # The device's path is outside text too: markup in a directory name.
    hostile = os.path.join(line.dir, "<b>&x")
    os.mkdir(hostile)
    device = os.path.join(hostile, "tty")
    os.symlink(line.device, device)
    port = free_port()
    try:
        # A delivery bound of 100 ms (16 by default): the retry sent at
        # once stays within it on a loaded host.
        with running(["--log-commands"], http_config(port) + rtu.rtu_config(
                device, rights="power", delivery_ms="100")) as (sim, gw):
            web = Http(port)
            wait_until(lambda: web.status()["policy"]["handler"] == "accepted", 15, "the handler")
            plc = ModbusPlc(gw.modbus_port)
            m = rtu.RawMaster(line.master)
            try:
                check(m.read_ir(rtu.IR_MAGIC) == [rtu.MAGIC], "the line answers")
                req = rtu.write_coil_pdu(COIL["cmd_power_on"], 1)
                check(m.request(rtu.UNIT, req) == rtu.frame(rtu.UNIT, req),
                      "power_on over the line")
                clients = plc.ir(IR["modbus_clients"])[0]
                samples = parse_metrics(web.metrics())
                by = {t: metric(samples, "jakagw_modbus_clients", transport=t)
                      for t in ("modbus", "mbaps", "rtu")}
                check(clients == 2 and by == {"modbus": 1, "mbaps": 0, "rtu": 1},
                      "clients: register %d, metrics %r" % (clients, by))
                check(metric(samples, "jakagw_modbus_requests_total", transport="rtu",
                             function="4") == 1 and
                      metric(samples, "jakagw_modbus_requests_total", transport="rtu",
                             function="5") == 1, "the line's requests by transport")
                m.quiet_until = 0  # the same write again as soon as the reply came
                check(m.request(rtu.UNIT, req) == rtu.frame(rtu.UNIT, req),
                      "power_on's write sent again at once answered again")
                m.send(rtu.frame(rtu.UNIT, bytes([0x85, 0x02])))
                m.no_reply()
                check(m.read_ir(rtu.IR_MAGIC) == [rtu.MAGIC], "the line answers after it")
                kinds = {k: metric(parse_metrics(web.metrics()), "jakagw_rtu_frames_total",
                                   kind=k) for k in ("repeat", "exception")}
                regs = {k: plc.u32(IR["rtu_%ss" % k]) for k in kinds}
                check(kinds == {"repeat": 1, "exception": 1} and regs == kinds,
                      "repeats and exception forms: metrics %r, registers %r" % (kinds, regs))
                wait_until(lambda: any(c["command"] == "power_on"
                                       for c in web.status()["commands"]), 10, "power_on recorded")
                status, headers, body = web.get("/status.json")
                check(b"<b>" not in body and b"&x" not in body, "the device's markup raw in JSON")
                doc = json.loads(body)
                line_clients = [c for c in doc["clients"] if c["transport"] == "rtu"]
                check(len(line_clients) == 1 and
                      device in line_clients[0]["peer"] + line_clients[0]["address"],
                      "the line in /status.json: %r" % doc["clients"])
                rec = [c for c in doc["commands"] if c["command"] == "power_on"][0]
                check(rec["transport"] == "rtu" and device in rec["client"], "record %r" % rec)
            finally:
                m.close()
                plc.close()
        audit = [a for a in audit_lines(gw) if a["command"] == "power_on"]
        check(len(audit) == 1 and audit[0]["transport"] == "rtu" and device in audit[0]["client"],
              "power_on's audit line: %r" % audit)
        print("  clients by transport %r; repeat and exception form counted %r; audit: "
              "transport=rtu client=%s" % (by, kinds, audit[0]["client"]))
    finally:
        os.unlink(device)
        os.rmdir(hostile)
        line.close()


def journal_fields(datagram):
    """The fields of one message of journald's native protocol."""
    fields, i = {}, 0
    while i < len(datagram):
        nl = datagram.index(b"\n", i)
        line = datagram[i:nl]
        if b"=" in line:
            key, value = line.split(b"=", 1)
            i = nl + 1
        else:  # KEY\n, a 64-bit little-endian length, the value, \n
            key = line
            size = struct.unpack("<Q", datagram[nl + 1:nl + 9])[0]
            value = datagram[nl + 9:nl + 9 + size]
            i = nl + 9 + size + 1
        fields[key.decode()] = value.decode("utf-8", "replace")
    return fields


def private_mount_namespace():
    """The unshare command line for a mount namespace whose mounts stay
    private, or None. unshare -m makes every mount private, which needs '/'
    to be a mount point; in a chroot (CI's) it is not, but where no mount
    this process sees is shared (CI's chroot runs in a private namespace),
    nothing mounted in a new namespace can reach another one."""
    if os.geteuid() != 0:
        return None
    if subprocess.run(["unshare", "-m", "true"], stderr=subprocess.DEVNULL).returncode == 0:
        return ["unshare", "-m"]
    try:
        with open("/proc/self/mountinfo") as f:
            shared = any(" shared:" in line.split(" - ")[0] for line in f)
    except OSError:
        return None
    if not shared and subprocess.run(
            ["unshare", "-m", "--propagation", "unchanged", "true"]).returncode == 0:
        return ["unshare", "-m", "--propagation", "unchanged"]
    return None


def test_audit_goes_to_the_journal_as_fields():
    """Under journald (stderr is the journal's stream), a record is a
    journal entry with JAKAGW_* fields, not a stderr line. journald is
    stood in for by a datagram socket at /run/systemd/journal/socket in a
    mount namespace of the gateway's own (unshare -m, as root)."""
    unshare = private_mount_namespace()
    if not unshare:
        print("  SKIP: needs root and unshare -m for a private /run/systemd/journal")
        return
    message = "arm <b>blocked</b>\nline two"
    journal_dir = tempfile.mkdtemp(prefix="jakagw-journal-")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(os.path.join(journal_dir, "socket"))
    listener.settimeout(0.2)
    log = tempfile.NamedTemporaryFile(prefix="jakagw-", suffix=".log", delete=False)
    conf = tempfile.NamedTemporaryFile("w", suffix=".conf", delete=False)
    conf.close()
    st = os.fstat(log.fileno())
    sim = Sim("--fail-command", "power_on", "--fail-message", message)
    modbus_port = free_port()
    script = ('mount -t tmpfs tmpfs /run && mkdir -p /run/systemd/journal && '
              'mount --bind "$JOURNAL_DIR" /run/systemd/journal && exec "$0" "$@"')
    argv = unshare + ["sh", "-c", script, JAKAGW, "-c", conf.name,
            "--robot-host", "127.0.0.1", "--status-port", str(sim.status_port),
            "--command-port", str(sim.command_port), "--modbus-bind", "127.0.0.1",
            "--modbus-port", str(modbus_port)]
    env = dict(os.environ, JOURNAL_DIR=journal_dir,
               JOURNAL_STREAM="%d:%d" % (st.st_dev, st.st_ino))
    proc = subprocess.Popen(argv, stdout=log, stderr=log, env=env)
    entries = []
    try:
        wait_until(lambda: port_open(modbus_port), 30, "jakagw to listen")
        plc = ModbusPlc(modbus_port)
        wait_until(lambda: plc.ir(IR["robot_handle"])[0] == 2, 20, "the robot's handler")
        check(plc.pulse(COIL["cmd_power_on"]) == 0, "power_on write")
        plc.close()

        def power_on_entry():
            try:
                entries.append(journal_fields(listener.recv(65536)))
            except socket.timeout:
                pass
            return [e for e in entries if e.get("JAKAGW_COMMAND") == "power_on"]
        found = wait_until(power_on_entry, 10, "power_on's journal entry")[0]
    finally:
        proc.send_signal(15)
        proc.wait(10)
        sim.stop()
        listener.close()
        shutil.rmtree(journal_dir, ignore_errors=True)
        os.unlink(conf.name)
        with open(log.name, errors="replace") as f:
            out = f.read()
        os.unlink(log.name)
    check(proc.returncode == 0, "jakagw exited %d:\n%s" % (proc.returncode, out[-2000:]))
    for mark in ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:"):
        check(mark not in out, "sanitizer report:\n" + out[-3000:])
    check(re.match(r"^127\.0\.0\.1:\d+$", found.get("JAKAGW_CLIENT", "")) and
          found.get("JAKAGW_REASON") == "" and
          found.get("JAKAGW_TRANSPORT") == "modbus" and
          found.get("JAKAGW_RESULT") == "robot error" and
          found.get("JAKAGW_ERROR_CODE") == "2" and found.get("JAKAGW_ROLE") == "" and
          found.get("PRIORITY") == "5" and found.get("SYSLOG_IDENTIFIER") == "jakagw",
          "journal entry %r" % found)
    check(found.get("JAKAGW_ERROR_MSG") == "arm <b>blocked</b>\\x0aline two",
          "errorMsg as one escaped line: %r" % found.get("JAKAGW_ERROR_MSG"))
    handler = [e for e in entries if e.get("JAKAGW_COMMAND") == "set_network_exception_handle"]
    check(handler and handler[0]["JAKAGW_TRANSPORT"] == "gateway", "the handler's entry")
    check("audit:" not in out, "audit lines on stderr under journald")
    print("  journal entry: %s" % " ".join("%s=%s" % kv for kv in sorted(found.items())
                                          if kv[0].startswith("JAKAGW_")))


def sim_sent(sim, name):
    return [l for l in sim.output().splitlines()
            if "jakasim: command {" in l and '"cmdName":"%s"' % name in l.replace(" ", "")]


# ---- bounds and abuse ----

class Poller(threading.Thread):
    """A PLC reading every 20 ms; records the worst wait and failures."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.plc = ModbusPlc(port, timeout=5)
        self.stop = threading.Event()
        self.worst = 0.0
        self.failures = 0
        self.reads = 0

    def run(self):
        while not self.stop.is_set():
            start = time.monotonic()
            try:
                self.plc.ir(0, 20)
                self.reads += 1
            except Exception:
                self.failures += 1
            self.worst = max(self.worst, time.monotonic() - start)
            time.sleep(0.02)

    def finish(self):
        self.stop.set()
        self.join(10)
        self.plc.close()


def raw_exchange(port, data, timeout=10):
    s = socket.create_connection(("127.0.0.1", port), timeout=timeout)
    try:
        s.sendall(data)
    except OSError:
        pass
    out = b""
    try:
        while True:
            d = s.recv(65536)
            if not d:
                break
            out += d
    except OSError:
        pass
    s.close()
    return out


def closed_within(sock, seconds):
    """Seconds until the server closed 'sock', or None."""
    start = time.monotonic()
    sock.settimeout(seconds)
    try:
        while True:
            d = sock.recv(4096)
            if not d:
                return time.monotonic() - start
    except socket.timeout:
        return None
    except OSError:
        return time.monotonic() - start


def test_abuse_leaves_modbus_answering():
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        poller = Poller(gw.modbus_port)
        poller.start()
        try:
            report = abuse(port, gw)
        finally:
            poller.finish()
        check(poller.failures == 0 and poller.reads > 50,
              "poller: %d failures, %d reads" % (poller.failures, poller.reads))
        check(poller.worst < 1.0, "a Modbus read waited %.3f s" % poller.worst)
        print("  %s; Modbus meanwhile: %d reads, none failed, worst %.1f ms"
              % (report, poller.reads, poller.worst * 1000))


def abuse(port, gw):
    web = Http(port)
    # Methods other than GET and HEAD.
    for method in ("POST", "PUT", "DELETE", "PATCH", "OPTIONS", "TRACE", "CONNECT"):
        status, headers, _ = web.get("/metrics", method=method)
        check(status == 405 and headers.get("Allow") == "GET, HEAD",
              "%s: %d %s" % (method, status, headers.get("Allow")))
    # A 64 KiB header, and a 9000-byte one (past 8 KiB, within the pool).
    for size in (65536, 9000):
        out = raw_exchange(port, b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Big: " +
                           b"a" * size + b"\r\n\r\n")
        check(out.startswith(b"HTTP/1.1 431 "), "%d-byte header: %r" % (size, out[:60]))
    # 100 requests pipelined in one write: 100 answers in order.
    out = raw_exchange(port, b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n" * 99 +
                       b"GET /status.json HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n")
    check(out.count(b"HTTP/1.1 200 OK") == 100 and b'"links"' in out[-20000:],
          "pipelined: %d answers" % out.count(b"HTTP/1.1 200 OK"))
    # 500 idle connections: the limit's worth held, the rest closed at once.
    idle = [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(500)]
    held = wait_until(lambda: (lambda n: n if n <= 40 else None)(
        sum(1 for s in idle if closed_within(s, 0.001) is None)), 20,
        "the connections over the limit to be closed")
    fds = len(os.listdir("/proc/%d/fd" % gw.proc.pid))
    check(fds < 100, "jakagw holds %d descriptors with 500 idle connections" % fds)
    for s in idle:
        s.close()
    wait_until(lambda: web.get("/metrics")[0] == 200, 20, "/metrics served again")
    # Slowloris: a header byte every second; the head deadline closes it.
    slow = socket.create_connection(("127.0.0.1", port), timeout=5)
    start = time.monotonic()
    head = b"GET /metrics HTTP/1.1\r\nX-Slow: " + b"a" * 100
    closed = None
    for i in range(40):
        try:
            slow.sendall(head[i:i + 1])
        except OSError:
            closed = time.monotonic() - start
            break
        if closed_within(slow, 1.0) is not None:
            closed = time.monotonic() - start
            break
    slow.close()
    check(closed is not None and 9 <= closed < 25, "slowloris closed after %s s" % closed)
    samples = parse_metrics(web.metrics())
    check(metric(samples, "jakagw_http_connections_refused_total") >= 400 and
          metric(samples, "jakagw_http_slow_closed_total") >= 1, "the abuse counted")
    return ("405 for 7 methods, 431 for 64 KiB, 100 pipelined answers, 500 idle connections: "
            "%d held, %d descriptors; slowloris closed after %.1f s" % (held, fds, closed))


def test_request_bodies_are_refused_not_read():
    """A GET or HEAD carries no body here: one announced (Content-Length or
    chunked) is answered 413 and the connection closed, instead of the
    body being read and dropped for as long as the client sends it (3.5 GB
    in 5 s on one connection, the loop's time taken from Modbus)."""
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        report = []
        for method, framing in ((b"GET", b"Content-Length: 100000000000"),
                                (b"HEAD", b"Transfer-Encoding: chunked")):
            s = socket.create_connection(("127.0.0.1", port), timeout=5)
            s.sendall(method + b" /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n" + framing + b"\r\n\r\n")
            sent, start = 0, time.monotonic()
            try:
                while time.monotonic() - start < 5:
                    sent += s.send(b"ffff\r\n" + b"a" * 65529)
            except OSError:
                pass
            took = time.monotonic() - start
            s.close()
            check(sent < 64 << 20 and took < 5,
                  "%s with a body: %d MB taken in %.1f s" % (method.decode(), sent >> 20, took))
            report.append("%s: %.1f MB, closed after %.2f s" % (method.decode(), sent / 1e6, took))
        out = raw_exchange(port, b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                           b"Content-Length: 5\r\n\r\nhello")
        check(out.startswith(b"HTTP/1.1 413 "), "a GET with a body: %r" % out[:60])
        out = raw_exchange(port, b"GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                           b"Content-Length: 0\r\nConnection: close\r\n\r\n")
        check(out.startswith(b"HTTP/1.1 200 "), "Content-Length: 0 is no body: %r" % out[:60])
        check(Http(port).get("/metrics")[0] == 200, "served after")
        print("  " + "; ".join(report))


# Thirty keep-alive connections, each pipelining 8 requests at a time for
# a while (its own process: the test's Modbus reader keeps its interpreter).
HAMMER = r"""
import socket, sys, threading, time
port, path, seconds = int(sys.argv[1]), sys.argv[2].encode(), float(sys.argv[3])
end, answers = time.monotonic() + seconds, [0]
def hammer():
    s = socket.create_connection(("127.0.0.1", port), timeout=20)
    while time.monotonic() < end:
        s.sendall((b"GET " + path + b" HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n") * 8)
        n = 0
        while n < 8:
            d = s.recv(1 << 20)
            if not d:
                return
            n += d.count(b"HTTP/1.1 200")
        answers[0] += 8
threads = [threading.Thread(target=hammer) for _ in range(30)]
[t.start() for t in threads]
[t.join() for t in threads]
print(answers[0])
"""


def test_busy_http_clients_leave_modbus_answering():
    """HTTP clients that always have a request waiting (pipelined, on 30
    connections, for the largest answer) keep the loop busy but must not
    keep it: a Modbus read meanwhile is answered within a fraction of a
    second. (libmicrohttpd's timeout is 0 while it has work left; a 0 ms
    timer restarted in its own callback ran again before any I/O, and a
    Modbus read waited until the HTTP clients stopped: 4.98 s of 5.)"""
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        mb = raw_client(gw.modbus_port, timeout=20)
        hammer = subprocess.Popen([sys.executable, "-c", HAMMER, str(port),
                                   "/status.json?registers=1", "4"],
                                  stdout=subprocess.PIPE, text=True)
        waits = []
        try:
            time.sleep(0.3)
            tid = 0
            while hammer.poll() is None:
                tid += 1
                start = time.monotonic()
                check(read_input_registers(mb, 0, 20, tid & 0xFFFF)[0] == 0x4A4B, "map magic")
                waits.append(time.monotonic() - start)
                time.sleep(0.02)
        finally:
            answers = hammer.communicate(timeout=30)[0].strip()
            mb.close()
        waits.sort()
        check(len(waits) >= 20 and waits[-1] < 1.0,
              "%d Modbus reads while HTTP was busy, the worst waited %.3f s"
              % (len(waits), waits[-1] if waits else 0))
        print("  %s HTTP answers in 4 s; Modbus meanwhile: %d reads, p50 %.1f ms, worst %.1f ms"
              % (answers, len(waits), waits[len(waits) // 2] * 1000, waits[-1] * 1000))


def test_non_loopback_bind_logs_one_warning():
    port = free_port()
    with running([], http_config(port, "bind = 0.0.0.0\n")) as (sim, gw):
        wait_until(lambda: Http(port).get("/")[0] == 200, 10, "the page")
        lines = log_lines(gw, "http: listening on 0.0.0.0")
        check(len(lines) == 1 and lines[0].startswith("<4>"), "warning lines: %r" % lines)
    with running([], http_config(port)) as (sim, gw):
        wait_until(lambda: Http(port).get("/")[0] == 200, 10, "the page")
        check(not log_lines(gw, "not only loopback"), "a warning for loopback")


def test_loopback_server_answers_only_its_own_host_names():
    """Bound to loopback, the server answers a Host that is an address or
    localhost (a browser on the gateway's host, an SSH tunnel, the README's
    reverse proxy) and refuses any other name with 403: a web page on that
    browser cannot rebind its own name to 127.0.0.1 and read /status.json.
    Bound elsewhere, names are the operator's choice and not checked."""
    def status_for(port, host):
        head = b"GET /status.json HTTP/1.1\r\n" + (b"Host: " + host + b"\r\n" if host else b"")
        out = raw_exchange(port, head + b"Connection: close\r\n\r\n")
        return int(out.split(b" ", 2)[1]) if out.startswith(b"HTTP/1.1 ") else out[:40]
    port = free_port()
    p = str(port).encode()
    with running([], http_config(port)) as (sim, gw):
        wait_http(port, gw)
        for host in (b"127.0.0.1:" + p, b"localhost:" + p, b"LOCALHOST", b"[::1]:" + p,
                     b"192.0.2.7", None):
            check(status_for(port, host) == 200, "Host %r: %r" % (host, status_for(port, host)))
        for host in (b"attacker.example:" + p, b"attacker.example", b"127.0.0.1.nip.io:" + p,
                     b"localhost.attacker.example", b"[::1]x", b"127.0.0.1:80:80"):
            check(status_for(port, host) == 403, "Host %r: %r" % (host, status_for(port, host)))
    with running([], http_config(port, "bind = 0.0.0.0\n")) as (sim, gw):
        wait_http(port, gw)
        check(status_for(port, b"gateway.plant.example:" + p) == 200, "a name, bound elsewhere")


def test_disabled_by_default():
    port = free_port()
    with running([], "[http]\nport = %d\n" % port) as (sim, gw):
        check(ModbusPlc(gw.modbus_port).ir(0, 1) == [0x4A4B], "Modbus up")
        try:
            Http(port).get("/", timeout=2)
            raise TestFailure("HTTP served while [http] enabled = false")
        except OSError:
            pass


# ---- the page, in a real browser ----

def browser(width=412, height=915):
    """Headless Chromium (Debian's), a fresh profile, a phone-sized window."""
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    profile = tempfile.mkdtemp(prefix="jakagw-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", "--user-data-dir=" + profile,
                 "--window-size=%d,%d" % (width, height)):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    driver.jakagw_profile = profile
    # A phone's viewport (Chromium's windows are at least 500 px wide).
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                           {"width": width, "height": height, "deviceScaleFactor": 2,
                            "mobile": True})
    return driver


def close_browser(driver):
    try:
        driver.quit()
    finally:
        shutil.rmtree(driver.jakagw_profile, ignore_errors=True)


def text_of(driver, element_id):
    """The element's text. The live page replaces elements as documents
    come: one found just before it was replaced is read again, found anew."""
    from selenium.common.exceptions import StaleElementReferenceException
    for _ in range(20):
        try:
            return driver.find_element("id", element_id).text
        except StaleElementReferenceException:
            continue
    return driver.find_element("id", element_id).text


def test_page_shows_links_commands_and_robot_markup_as_text():
    message = '<img src=x onerror="document.title=\'pwned\'"><b>bold</b><script>alert(1)</script>'
    port, ctx = gateway_with_http(["--fail-command", "power_on", "--fail-message", message])
    with ctx as (sim, gw):
        web = Http(port)
        status, headers, body = web.get("/")
        check(status == 200 and headers["Content-Type"].startswith("text/html") and
              "default-src 'none'" in headers.get("Content-Security-Policy", ""),
              "page headers %r" % headers)
        check(not re.search(rb'(src|href)\s*=\s*"(https?:)?//', body), "an external asset")
        driver = browser()
        try:
            driver.get("http://127.0.0.1:%d/" % port)
            wait_until(lambda: text_of(driver, "status-link") == "connected" and
                       text_of(driver, "command-link") == "connected", 15, "the links on the page")
            age = text_of(driver, "status-age")
            check(re.match(r"^\d+ ms$", age), "status age shown as %r" % age)
            check("tile ok" in driver.find_element("id", "tile-status").get_attribute("class"),
                  "the status link in green")
            plc = ModbusPlc(gw.modbus_port)
            wait_until(lambda: web.status()["policy"]["handler"] == "accepted", 15, "the handler")
            check(plc.pulse(COIL["cmd_power_on"]) == 0, "power_on write")
            wait_until(lambda: "power_on" in text_of(driver, "commands"), 10,
                       "power_on's result on the page")
            shown = [e.text for e in driver.find_elements("css selector", "#commands .msg")]
            check(any(message in t for t in shown), "errmsg not shown as text: %r" % shown)
            check(not driver.find_elements("css selector", "#commands img, #commands b, "
                                                           "#commands script"),
                  "the robot's markup became elements")
            check(driver.title == "jakagw", "title changed to %r" % driver.title)
            check("robot error" in text_of(driver, "commands") and
                  "modbus 127.0.0.1" in text_of(driver, "commands"), "who and the result")
            check("127.0.0.1" in text_of(driver, "clients"), "the client listed")
            # The register map, searched by address and by name.
            driver.find_element("css selector", "#map summary").click()
            box = driver.find_element("id", "search")
            box.send_keys("0")
            wait_until(lambda: "map_magic" in text_of(driver, "registers"), 10, "address 0")
            box.clear()
            box.send_keys("plc_heartbeat")
            check(plc.reg(0, 4321) == 0, "heartbeat write")
            wait_until(lambda: "4321" in text_of(driver, "registers"), 10,
                       "the heartbeat's live value")
            plc.close()
            width = driver.execute_script("return [document.documentElement.scrollWidth, "
                                          "window.innerWidth]")
            check(width[0] <= width[1] == 412, "the page scrolls sideways on a phone: %r" % width)
        finally:
            close_browser(driver)


def test_page_says_when_the_gateway_stops_answering():
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        driver = browser()
        try:
            driver.get("http://127.0.0.1:%d/" % port)
            wait_until(lambda: text_of(driver, "status-link") == "connected", 15, "the page")
            check(not driver.find_element("id", "banner").is_displayed(), "banner while fine")
            gw.proc.send_signal(19)  # SIGSTOP: the gateway hangs
            try:
                wait_until(lambda: "stopped answering" in text_of(driver, "banner"), 15,
                           "the banner")
            finally:
                gw.proc.send_signal(18)  # SIGCONT
            wait_until(lambda: not driver.find_element("id", "banner").is_displayed(), 15,
                       "the banner to go once it answers again")
        finally:
            close_browser(driver)


# ---- the robot on the page (issue 30) ----

ROBOT_TILES = ("power", "enabled", "program", "estop", "pstop")


def tiles_fit(driver):
    """Tiles whose value is wider than the tile (cut off), and whether the
    page scrolls sideways."""
    return driver.execute_script("""
        const cut = [...document.querySelectorAll('.tile span')]
          .filter((s) => s.scrollWidth > s.clientWidth + 1).map((s) => s.id + '=' + s.textContent);
        return [cut, document.documentElement.scrollWidth, window.innerWidth];""")


def words_broken(driver):
    """Words in the tiles that the browser broke inside themselves: each
    word's text range must lie on one line (one line box top)."""
    return driver.execute_script("""
        const broken = [];
        for (const e of document.querySelectorAll('.tile b, .tile span, .tile small')) {
          for (const node of e.childNodes) {
            if (node.nodeType !== Node.TEXT_NODE) continue;
            for (const m of node.textContent.matchAll(/\\S+/g)) {
              const r = document.createRange();
              r.setStart(node, m.index);
              r.setEnd(node, m.index + m[0].length);
              const tops = new Set([...r.getClientRects()].filter((x) => x.width > 0)
                                   .map((x) => Math.round(x.top)));
              if (tops.size > 1) broken.push(e.id + ':' + m[0]);
            }
          }
        }
        return broken;""")


def tile_class(driver, name):
    return driver.find_element("id", "tile-" + name).get_attribute("class")


def header_is_red(driver):
    head = driver.find_element("css selector", "header")
    return "fault" in head.get_attribute("class") and \
        head.value_of_css_property("background-color") in ("rgba(198, 40, 40, 1)",
                                                            "rgb(198, 40, 40)")


def test_page_shows_the_robot_first_at_phone_and_desktop_width():
    """Power, enabled, the program with its name, both stops and the links
    in the header tiles, in /status.json's robot, at 390 px and 1280 px;
    the PLC's commands apart from the gateway's own."""
    port, ctx = gateway_with_http(["--auto-run"])
    with ctx as (sim, gw):
        web = Http(port)
        wait_until(lambda: web.status()["robot"]["program_state"] == "running" and
                   web.status()["robot"]["loaded_program"], 15, "the program in /status.json")
        robot = web.status()["robot"]
        check(robot["known"] and robot["powered_on"] is True and robot["enabled"] is True and
              robot["emergency_stop"] is False and robot["protective_stop"] is False and
              0 <= robot["speed_override"] <= 1 and robot["mode"], "robot %r" % robot)
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: web.status()["policy"]["handler"] == "accepted", 15, "the handler")
        check(plc.coil(COIL["cabinet_do_1"], 1) == 0, "an output")
        plc.close()
        for width, height in ((390, 844), (1280, 900)):
            driver = browser(width, height)
            try:
                driver.get("http://127.0.0.1:%d/" % port)
                wait_until(lambda: text_of(driver, "program") == "running", 15,
                           "the program tile at %d px" % width)
                check(text_of(driver, "power") == "on" and text_of(driver, "enabled") ==
                      "enabled" and text_of(driver, "estop") == "released" and
                      text_of(driver, "pstop") == "released",
                      "tiles at %d px: %r" % (width, [text_of(driver, t) for t in ROBOT_TILES]))
                check(robot["loaded_program"] in text_of(driver, "program-name"),
                      "the program's name on its tile")
                check("ok" in driver.find_element("id", "tile-program").get_attribute("class"),
                      "running in green")
                check(not header_is_red(driver), "a red header without a fault")
                wait_until(lambda: "set_digital_output" in text_of(driver, "commands"), 10,
                           "the PLC's command")
                check("set_network_exception_handle" not in text_of(driver, "commands"),
                      "the gateway's own command among the PLC's")
                check("program: running" in text_of(driver, "events"), "the event log")
                cut, scroll, inner = tiles_fit(driver)
                check(not cut and scroll <= inner == width,
                      "at %d px: cut off %r, page %d wide in %d" % (width, cut, scroll, inner))
                check(not words_broken(driver), "at %d px, words broken inside: %r"
                      % (width, words_broken(driver)))
                check(text_of(driver, "fault-tile") == "none" and
                      "ok" in tile_class(driver, "policy"), "no fault, robot known: green")
                # No PLC ever wrote the heartbeat: "never", in amber.
                beat = driver.find_element("xpath", "//dl[@id='policy']/dt[.='PLC heartbeat']"
                                                    "/following-sibling::dd[1]")
                check(beat.text == "never" and "amber" in beat.get_attribute("class"),
                      "PLC heartbeat shown as %r (%s)" % (beat.text, beat.get_attribute("class")))
                check(not driver.find_element("id", "outage").is_displayed(),
                      "an outage banner with both links up")
                print("  %d px: %s" % (width, " | ".join(text_of(driver, t)
                                                          for t in ROBOT_TILES)))
            finally:
                close_browser(driver)
        own = [c["command"] for c in web.status()["gateway_commands"]]
        check("set_network_exception_handle" in own, "the gateway's own commands: %r" % own)


def test_page_latched_fault_turns_the_header_red_with_how_to_reset():
    """A PLC stops its heartbeat while a program runs: fault 1 latches, the
    header turns red and its banner says what, when and how the PLC resets
    it; a refused command carries that reason in the audit; the reset
    clears the banner and is recorded."""
    port, ctx = gateway_with_http(["--auto-run"], "[network_exception]\ntime_limit_ms = 500\n")
    with ctx as (sim, gw):
        web = Http(port)
        plc = ModbusPlc(gw.modbus_port)
        wait_until(lambda: web.status()["policy"]["handler"] == "accepted" and
                   web.status()["robot"]["program_state"] == "running", 15, "a running program")
        driver = browser(390, 844)
        try:
            driver.get("http://127.0.0.1:%d/" % port)
            wait_until(lambda: text_of(driver, "program") == "running", 15, "the page")
            for beat in range(1, 4):
                check(plc.reg(0, beat) == 0, "heartbeat")
                time.sleep(0.1)
            t0 = time.time()
            wait_until(lambda: web.status()["policy"]["fault"] == 1, 10, "fault 1")
            wait_until(lambda: header_is_red(driver), 10, "the header to turn red")
            banner = text_of(driver, "fault")
            check("PLC heartbeat lost" in banner and "coil %d" % COIL["fault_reset"] in banner and
                  "holding register 0" in banner and "pause_program" in banner,
                  "banner %r" % banner)
            # What the robot did, not only what was sent (IR 5602).
            wait_until(lambda: "pause_program; the robot: paused" in text_of(driver, "fault"),
                       5, "the reaction on the page")
            banner = text_of(driver, "fault")
            shown = re.search(r" at (\d\d):(\d\d):(\d\d)", banner)
            check(shown, "no time in %r" % banner)
            check(text_of(driver, "fault-tile") == "latched", "the fault tile")
            wait_until(lambda: "fault 1 latched" in text_of(driver, "events"), 10,
                       "the fault in the event log")
            driver.save_screenshot(os.path.join(tempfile.gettempdir(), "jakagw-fault.png"))
            # A command while it is latched: refused, the reason recorded.
            check(plc.pulse(COIL["cmd_resume_program"]) == 1, "resume refused with 01")
            wait_until(lambda: [c for c in web.status()["commands"]
                                if c["command"] == "write"], 10, "the refusal")
            rec = [c for c in web.status()["commands"] if c["command"] == "write"][0]
            check(rec["reason"] == "fault 1 latched: reset it first" and
                  rec["what"] == "coil %d resume_program" % COIL["cmd_resume_program"] and
                  re.match(r"^127\.0\.0\.1:\d+$", rec["client"]), "refusal %r" % rec)
            # The page gives the reason beside the exception.
            wait_until(lambda: "Modbus exception 01: fault 1 latched: reset "
                       "it first" in text_of(driver, "commands"), 10, "the reason on the page")
            check(plc.reg(0, 10) == 0 and plc.coil(COIL["fault_reset"], 1) == 0, "the reset")
            wait_until(lambda: not driver.find_element("id", "fault").is_displayed() and
                       not header_is_red(driver), 10, "the banner to go after the reset")
            check("reset by the PLC" in text_of(driver, "events"), "the reset in the event log")
            resets = [c for c in web.status()["commands"] if c["command"] == "fault_reset"]
            check(resets and resets[0]["what"] == "fault 1 (PLC heartbeat lost)" and
                  resets[0]["client"] == rec["client"], "the reset audited: %r" % resets)
            print("  banner: %s (%.1f s after the last beat)" % (banner, time.time() - t0))
        finally:
            close_browser(driver)
            plc.close()


def test_page_shows_a_pressed_emergency_stop_and_a_protective_stop():
    """The robot's own stops, from jakasim's signals (SIGRTMIN: emergency
    stop pressed, the robot disabled and its program stopped; SIGUSR2:
    protective stop): both in /status.json's robot and red on their tiles,
    and back to released when they are."""
    import signal
    port, ctx = gateway_with_http(["--auto-run"])
    with ctx as (sim, gw):
        web = Http(port)
        wait_until(lambda: web.status()["robot"]["program_state"] == "running", 15,
                   "the program running")
        driver = browser(390, 844)
        try:
            driver.get("http://127.0.0.1:%d/" % port)
            wait_until(lambda: text_of(driver, "estop") == "released", 15, "the page")
            sim.proc.send_signal(signal.SIGRTMIN)
            wait_until(lambda: web.status()["robot"]["emergency_stop"] is True, 5,
                       "emergency_stop in /status.json")
            wait_until(lambda: text_of(driver, "estop") == "TRIGGERED", 5, "the tile")
            check("bad" in driver.find_element("id", "tile-estop").get_attribute("class"),
                  "a pressed emergency stop not in red")
            wait_until(lambda: web.status()["robot"]["enabled"] is False and
                       web.status()["robot"]["program_state"] != "running", 5,
                       "the robot disabled, the program stopped")
            check(text_of(driver, "pstop") == "released", "protective stop with the button")
            sim.proc.send_signal(signal.SIGUSR2)
            wait_until(lambda: text_of(driver, "pstop") == "TRIGGERED", 5, "protective stop")
            check(web.status()["robot"]["protective_stop"] is True, "protective_stop")
            print("  both stops: %s" % " | ".join(text_of(driver, t) for t in ROBOT_TILES))
            sim.proc.send_signal(signal.SIGRTMIN)
            sim.proc.send_signal(signal.SIGUSR2)
            wait_until(lambda: text_of(driver, "estop") == "released" and
                       text_of(driver, "pstop") == "released", 5, "both released")
        finally:
            close_browser(driver)


def test_page_shows_unknown_during_an_outage():
    """The status stream goes silent on an open connection, then the robot
    goes away: every value that depends on the status link reads
    "unknown" (no old program, no "none" for the error), in /status.json
    as null, and "disconnected" fits its tile at 390 px."""
    port, ctx = gateway_with_http(["--auto-run", "--silent-after-ms", "6000"])
    with ctx as (sim, gw):
        web = Http(port)
        driver = browser(390, 844)
        try:
            driver.get("http://127.0.0.1:%d/" % port)
            wait_until(lambda: text_of(driver, "program") == "running", 15, "the page")
            wait_until(lambda: web.status()["robot"]["known"] is False, 20, "the status stale")
            robot = web.status()["robot"]
            nulls = ("powered_on", "enabled", "program_state", "loaded_program", "emergency_stop",
                     "protective_stop", "speed_override", "mode", "errcode", "errmsg")
            check(all(robot[k] is None for k in nulls), "stale robot %r" % robot)
            wait_until(lambda: all(text_of(driver, t) == "unknown" for t in ROBOT_TILES), 10,
                       "unknown tiles")
            # No fault latched, but the gateway cannot see the robot: the
            # fault tile is grey "unknown", not a green "none".
            check(text_of(driver, "fault-tile") == "unknown" and
                  tile_class(driver, "policy").split() == ["tile"],
                  "fault tile %r %r" % (text_of(driver, "fault-tile"),
                                        tile_class(driver, "policy")))
            wait_until(lambda: re.search(r"status link (stale|silent)", text_of(driver, "outage")),
                       10, "the outage banner")
            check("sends no status" in text_of(driver, "outage"), "what to check: %r"
                  % text_of(driver, "outage"))
            check(text_of(driver, "program-name") == "", "the old program's name still shown")
            robot_panel = text_of(driver, "robot")
            check("none" not in robot_panel and robot_panel.count("unknown") >= 4,
                  "robot panel %r" % robot_panel)
            sim.proc.send_signal(15)
            sim.proc.wait(10)
            wait_until(lambda: text_of(driver, "status-link") in ("disconnected", "connecting"),
                       15, "the status link down")
            wait_until(lambda: text_of(driver, "status-link") == "disconnected", 15,
                       "disconnected shown")
            cut, scroll, inner = tiles_fit(driver)
            check(not cut and scroll <= inner, "cut off %r, page %d wide in %d"
                  % (cut, scroll, inner))
            check(not words_broken(driver),
                  "390 px, words broken inside: %r" % words_broken(driver))
            check(all(text_of(driver, t) == "unknown" for t in ROBOT_TILES), "tiles while down")
            check(text_of(driver, "fault-tile") == "unknown", "fault tile while down")
            outage = text_of(driver, "outage")
            check("status link disconnected" in outage and "switched on" in outage and
                  "127.0.0.1" in outage and "jakagw.conf" in outage, "outage banner %r" % outage)
            print("  outage: %s" % outage.replace("\n", " / "))
            wide = browser(1280, 900)
            try:
                wide.get("http://127.0.0.1:%d/" % port)
                wait_until(lambda: text_of(wide, "status-link") == "disconnected", 15,
                           "disconnected at 1280 px")
                cut, scroll, inner = tiles_fit(wide)
                check(not cut and scroll <= inner and not words_broken(wide),
                      "1280 px: cut off %r, broken %r" % (cut, words_broken(wide)))
            finally:
                close_browser(wide)
            events = text_of(driver, "events")
            check("robot state unknown" in events and "status link: disconnected" in events,
                  "events %r" % events[:300])
        finally:
            close_browser(driver)


def test_registers_document_is_served_from_its_cache():
    """/status.json?registers=1 (about 90 KB) back to back: the median
    fetch on loopback and the gateway's CPU per request stay small (the
    bounds here are generous; make bench-http-registers prints the
    figures under the Modbus load)."""
    port, ctx = gateway_with_http(["--period-ms", "8", "--auto-run"])
    with ctx as (sim, gw):
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
        times = []
        ticks = os.sysconf("SC_CLK_TCK")

        def cpu():
            with open("/proc/%d/stat" % gw.proc.pid) as f:
                fields = f.read().rsplit(")", 1)[1].split()
            return (int(fields[11]) + int(fields[12])) / ticks
        c0, w0 = cpu(), time.monotonic()
        # Instrumented, no time is judged: 40 fetches serve the document
        # from its cache as well as 400 do (53 s under ASan before).
        for _ in range(40 if instrumented() else 400):
            t = time.perf_counter()
            conn.request("GET", "/status.json?registers=1")
            body = conn.getresponse().read()
            times.append(time.perf_counter() - t)
        used = cpu() - c0
        conn.close()
        # Less the status stream's own CPU over as long a window.
        idle0 = cpu()
        time.sleep(time.monotonic() - w0)
        used -= cpu() - idle0
        doc = json.loads(body)
        check(len(doc["registers"]) > 2000 and doc["robot"]["known"], "the document")
        times.sort()
        median = times[len(times) // 2] * 1e3
        per_request = used / len(times) * 1e3
        print("  %d bytes: median fetch %.2f ms, gateway CPU %.2f ms per request"
              % (len(body), median, per_request))
        if instrumented():
            print("  (sanitizer, valgrind or qemu: no time bound)")
            return
        # Generous: this machine is shared (0.2-0.5 ms median when quiet,
        # 13.7 ms and 7.25 ms of CPU before the cache).
        check(median <= 10.0, "median fetch %.2f ms (bound 10 ms; 1.5 ms on a quiet machine)"
              % median)
        check(per_request <= 2.0, "%.2f ms of CPU per request (7.25 ms before the cache)"
              % per_request)


# One keep-alive client fetching 'path' back to back for 'seconds'.
FETCHER = r"""
import http.client, sys, time
port, path, end = int(sys.argv[1]), sys.argv[2], time.time() + float(sys.argv[3])
c = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
while time.time() < end:
    c.request("GET", path)
    c.getresponse().read()
"""


def test_new_connections_are_accepted_while_fetchers_keep_http_resting():
    """16 clients fetching /status.json?registers=1 back to back keep HTTP
    resting after every turn (HTTP_LOOP_PERCENT): a scraper's new
    connection must still be taken at the end of a rest, not only when a
    turn happens to be short. (The rest's end started the listener's poll
    and ran a long turn that stopped it again: /metrics on a new
    connection waited p90 1.37 s and 2 of 30 timed out after 2 s, which
    a Prometheus scraping every second counts as the gateway down.)"""
    port, ctx = gateway_with_http(["--period-ms", "8", "--auto-run"])
    with ctx as (sim, gw):
        fetchers = [subprocess.Popen([sys.executable, "-c", FETCHER, str(port),
                                      "/status.json?registers=1", "8"]) for _ in range(16)]
        waits = []
        try:
            time.sleep(1)
            for _ in range(30):
                start = time.monotonic()
                try:
                    c = http.client.HTTPConnection("127.0.0.1", port, timeout=2)
                    c.request("GET", "/metrics")
                    ok = c.getresponse().status == 200
                    c.close()
                except OSError:
                    ok = False
                waits.append(time.monotonic() - start if ok else 99)
                time.sleep(0.1)
        finally:
            for f in fetchers:
                f.wait(timeout=30)
        waits.sort()
        bound = 3.0 if instrumented() else 1.0
        check(waits[-1] < bound, "/metrics on a new connection, 16 fetchers running: %d of 30 "
              "failed, p90 %.2f s, worst %.2f s (bound %.1f s, a 1 s scrape's timeout)"
              % (sum(1 for w in waits if w == 99), waits[26], waits[-1], bound))
        print("  /metrics on a new connection with 16 fetchers: median %.1f ms, worst %.1f ms"
              % (waits[15] * 1e3, waits[-1] * 1e3))


def test_idle_connections_cannot_lock_out_the_scraper():
    """A local process holding the connection limit's worth of idle
    connections (re-opening each one the server closes) must not lock
    Prometheus out: a new connection takes the place of the longest idle
    one (idle for HTTP_EVICT_IDLE_MS, 100 ms). (It was closed at once: /metrics
    refused on 10 of 10 tries, and JakagwDown would fire on a healthy
    gateway.)"""
    port, ctx = gateway_with_http()
    with ctx as (sim, gw):
        idle = []
        stop = threading.Event()

        def hold():
            while not stop.is_set():
                for i, s in enumerate(idle):
                    if closed_within(s, 0.001) is not None:
                        s.close()
                        try:
                            idle[i] = socket.create_connection(("127.0.0.1", port), timeout=5)
                        except OSError:
                            pass
                stop.wait(0.05)
        idle.extend(socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(40))
        holder = threading.Thread(target=hold, daemon=True)
        holder.start()
        results = []
        try:
            time.sleep(1.5)
            for _ in range(10):
                try:
                    c = http.client.HTTPConnection("127.0.0.1", port, timeout=2)
                    c.request("GET", "/metrics")
                    results.append(c.getresponse().status)
                    c.close()
                except OSError as e:
                    results.append(type(e).__name__)
                time.sleep(0.3)
        finally:
            stop.set()
            holder.join(5)
            for s in idle:
                s.close()
        ok = sum(1 for r in results if r == 200)
        check(ok >= 9, "/metrics with 40 idle connections held: %d of 10 answered: %r"
              % (ok, results))
        print("  /metrics with 40 idle connections held open: %d of 10 answered" % ok)


def instrumented():
    """ASan, valgrind or qemu-user make every request many times slower."""
    if os.environ.get("JAKAGW_VALGRIND") == "1" or os.environ.get("JAKAGW_RUNNER"):
        return True
    out = subprocess.run(["ldd", JAKAGW], capture_output=True).stdout
    return b"libasan" in out


# ---- alert rules ----

def test_alert_rules_check_and_unit_tests():
    r = promtool("check", "rules", ALERTS)
    check(r.returncode == 0, "promtool check rules:\n%s%s" % (r.stdout, r.stderr))
    r = promtool("test", "rules", ALERTS_TEST)
    check(r.returncode == 0 and "SUCCESS" in r.stdout + r.stderr,
          "promtool test rules:\n%s%s" % (r.stdout, r.stderr))


TESTS = [
    test_metrics_pass_promtool_and_carry_the_fixed_names,
    test_values_follow_modbus_and_equal_the_diagnostics_registers,
    test_status_json_clients_policy_and_counters,
    test_markup_from_the_robot_stays_text_in_json_and_audit,
    test_audit_records_commands_refusals_and_aggregates_outputs,
    test_audit_goes_to_the_journal_as_fields,
    test_writes_refused_by_the_map_are_audited,
    test_mbaps_clients_are_audited_with_certificate_and_role,
    test_rtu_line_is_transport_rtu_in_metrics_status_and_audit,
    test_abuse_leaves_modbus_answering,
    test_request_bodies_are_refused_not_read,
    test_busy_http_clients_leave_modbus_answering,
    test_non_loopback_bind_logs_one_warning,
    test_disabled_by_default,
    test_loopback_server_answers_only_its_own_host_names,
    test_alert_rules_check_and_unit_tests,
    test_page_shows_links_commands_and_robot_markup_as_text,
    test_page_says_when_the_gateway_stops_answering,
    test_page_shows_the_robot_first_at_phone_and_desktop_width,
    test_page_latched_fault_turns_the_header_red_with_how_to_reset,
    test_page_shows_a_pressed_emergency_stop_and_a_protective_stop,
    test_page_shows_unknown_during_an_outage,
    test_registers_document_is_served_from_its_cache,
    test_new_connections_are_accepted_while_fetchers_keep_http_resting,
    test_idle_connections_cannot_lock_out_the_scraper,
]

if __name__ == "__main__":
    picked = [t for t in TESTS if not sys.argv[1:] or any(a in t.__name__ for a in sys.argv[1:])]
    # JAKAGW_BROWSER_TESTS=0 (tests/run.sh, for every build but the first):
    # the page's own tests in Chromium run once; the gateway's side of
    # them (GET /, /status.json) is in the other cases.
    if os.environ.get("JAKAGW_BROWSER_TESTS") == "0":
        picked = [t for t in picked if not t.__name__.startswith("test_page_")]
    run(picked)
