#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""Every status entry of the register map, read over Modbus by pymodbus,
equals the value in the document jakasim sent.

For each configuration (simulator test pattern, two recorded real
documents, both word orders) the test reads the whole discrete-input and
input-register tables, then checks every row of `jakagw --print-map csv`
whose source is a status field, and every presence and count row.
"""
import json
import math
import re
import struct

from pymodbus.client import ModbusTcpClient

from harness import (DATA, Gateway, Sim, TestFailure, check, map_rows, run,
                     wait_until)

MISSING = object()
RANGES = {"u16": (0, 65535), "i16": (-32768, 32767),
          "u32": (0, 4294967295), "i32": (-2147483648, 2147483647)}


def resolve(doc, path):
    node = doc
    for key, index in re.findall(r"\.?([A-Za-z_][A-Za-z_0-9 ]*)|\[(\d+)\]", path):
        if key:
            if not isinstance(node, dict) or key not in node:
                return MISSING
            node = node[key]
        else:
            i = int(index)
            if not isinstance(node, list) or i >= len(node):
                return MISSING
            node = node[i]
    return node


def as_number(v, errcode=False):
    if isinstance(v, bool):
        return 1.0 if v else 0.0
    if isinstance(v, (int, float)):
        if errcode and v < 0:
            v += 2 ** 32
        return float(v)
    if isinstance(v, str) and v:
        try:
            return float(int(v, 0)) if v.lower().startswith(("0x", "-0x")) else float(v)
        except ValueError:
            return MISSING
    return MISSING


def read_table(client, kind, size):
    values = []
    step = 2000 if kind == "bits" else 125
    for start in range(0, size, step):
        n = min(step, size - start)
        if kind == "bits":
            rr = client.read_discrete_inputs(start, n, slave=1)
            check(not rr.isError(), "read discrete inputs %d+%d: %s" % (start, n, rr))
            values += rr.bits[:n]
        else:
            rr = client.read_input_registers(start, n, slave=1)
            check(not rr.isError(), "read input registers %d+%d: %s" % (start, n, rr))
            values += rr.registers
    return values


def words32(regs, low_first):
    hi, lo = (regs[1], regs[0]) if low_first else (regs[0], regs[1])
    return struct.pack(">HH", hi, lo)


def expected_int(value, typ, scale):
    v = round(value * scale)
    lo, hi = RANGES[typ]
    return min(max(v, lo), hi)


def check_row(row, doc, bits, regs, low_first, capacity):
    typ, addr, count = row["type"], int(row["address"]), int(row["count"])
    scale = float(row["scale"])
    source = row["source"]
    where = "%s %s (%s)" % (row["table"], addr, source)

    m = re.fullmatch(r"gw:(present|count)\((.*)\)", source)
    if m:
        kind, template = m.groups()
        if "*" in template:
            prefix, suffix = template.split("[*]", 1)
            carried = 0
            first, cap = capacity[template]
            for i in range(cap):
                if resolve(doc, "%s[%d]%s" % (prefix, first + i, suffix)) is not MISSING:
                    carried = i + 1
        else:
            carried = 0 if resolve(doc, template) is MISSING else 1
        got = bits[addr] if kind == "present" else regs[addr]
        want = int(carried > 0) if kind == "present" else carried
        check(got == want, "%s: read %s, the document carries %s" % (where, got, want))
        return

    value = resolve(doc, source)
    if typ == "bool":
        want = int(value is not MISSING and as_number(value) not in (MISSING, 0.0))
        check(bits[addr] == want, "%s: read %d, expected %d (document: %r)"
              % (where, bits[addr], want, value))
        return
    cells = regs[addr:addr + count]
    if typ == "str":
        raw = b"".join(struct.pack(">H", r) for r in cells).rstrip(b"\0").decode("latin-1")
        if value is MISSING or not isinstance(value, (str, int, float)):
            want = ""
        elif isinstance(value, str):
            want = value.encode("utf-8")[:2 * count].decode("latin-1")
        else:
            want = "%.15g" % value
        check(raw == want, "%s: read %r, expected %r" % (where, raw, want))
        return
    number = MISSING if value is MISSING else as_number(value, source == "errcode")
    if typ == "f32":
        got = struct.unpack(">f", words32(cells, low_first))[0]
        if number is MISSING:
            check(math.isnan(got), "%s: absent value read %r, expected NaN" % (where, got))
        else:
            want = struct.unpack(">f", struct.pack(">f", number * scale))[0]
            check(got == want, "%s: read %r, expected %r" % (where, got, want))
        return
    if typ in ("u32", "i32"):
        got = struct.unpack(">I" if typ == "u32" else ">i", words32(cells, low_first))[0]
    else:
        got = cells[0] if typ == "u16" else struct.unpack(">h", struct.pack(">H", cells[0]))[0]
    want = 0 if number is MISSING else expected_int(number, typ, scale)
    check(got == want, "%s: read %d, expected %d (document: %r)" % (where, got, want, value))


def status_capacities(rows):
    """(first index, capacity) of each array field, from its count row."""
    caps = {}
    for r in rows:
        m = re.fullmatch(r"gw:count\((.*)\)", r["source"])
        if m:
            first, last = map(int, re.search(r"indices (\d+) to (\d+)", r["description"]).groups())
            caps[m.group(1)] = (first, last - first + 1)
    return caps


def verify(sim_args, config="", low_first=False):
    rows = map_rows()
    caps = status_capacities(rows)
    sim = Sim(*sim_args)
    gw = None
    try:
        doc_bytes = sim.read_document()
        doc = json.loads(doc_bytes)
        check(doc["len"] == len(doc_bytes), "jakasim's len %d is not the size %d"
              % (doc["len"], len(doc_bytes)))
        gw = Gateway(sim, config)
        client = ModbusTcpClient("127.0.0.1", port=gw.modbus_port, timeout=5)
        check(client.connect(), "pymodbus cannot connect")
        try:
            wait_until(lambda: client.read_discrete_inputs(2, 1, slave=1).bits[0], 10,
                       "status_fresh")
            di_size = max(int(r["address"]) + 1 for r in rows if r["table"] == "discrete_input")
            ir_size = max(int(r["address"]) + int(r["count"]) for r in rows
                          if r["table"] == "input_register")
            bits = read_table(client, "bits", di_size)
            regs = read_table(client, "regs", ir_size)
        finally:
            client.close()
        checked = 0

        def is_status(r):
            return (not r["source"].startswith(("gw:", "cmd:"))
                    or r["source"].startswith(("gw:present(", "gw:count(")))

        for row in rows:
            if not is_status(row):
                continue
            if row["table"] not in ("discrete_input", "input_register"):
                continue
            check_row(row, doc, bits, regs, low_first, caps)
            checked += 1
        # The self-description block.
        check(regs[0] == 0x4A4B, "map magic %04x" % regs[0])
        check(regs[4] == (1 if low_first else 0), "word order register %d" % regs[4])
        check(struct.unpack(">f", words32(regs[6:8], low_first))[0] == -1234.5, "f32 probe")
        check(struct.unpack(">I", words32(regs[8:10], low_first))[0] == 0x01020304, "u32 probe")
        status_rows = sum(1 for r in rows if is_status(r))
        check(checked == status_rows, "checked %d of %d status rows" % (checked, status_rows))
        print("  checked %d map entries" % checked)
    finally:
        if gw:
            gw.stop()
        sim.stop()


def test_simulator_test_pattern_every_entry():
    verify(["--test-pattern", "--profile", "full"])


def test_low_word_first():
    verify(["--test-pattern", "--profile", "full"], "[modbus]\nword_order = low_first\n",
           low_first=True)


def test_manual_profile_shorter_arrays():
    verify(["--test-pattern", "--profile", "manual"])


def test_real_zu5s_document():
    verify(["--replay", DATA + "/status-zu5s-1.5.14.json"])


def test_real_controller_a_document():
    verify(["--replay", DATA + "/status-controller-a.json"])


if __name__ == "__main__":
    run([test_simulator_test_pattern_every_entry, test_low_word_first,
         test_manual_profile_shorter_arrays, test_real_zu5s_document,
         test_real_controller_a_document])
