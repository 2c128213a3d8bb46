#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""jakagw's command line: the generated docs are current, a bad flag or
configuration gets one line naming the key and exit code 2."""
import csv
import io
import os
import re
import subprocess
import tempfile

from harness import JAKAGW, JAKASIM, TestFailure, check, free_port, print_map, run

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def jakagw(*args, config=None):
    return subprocess.run([JAKAGW] + list(args), capture_output=True, text=True, timeout=10)


def test_committed_register_map_is_current():
    for fmt, path in (("md", "docs/register-map.md"), ("csv", "docs/register-map.csv"),
                      ("st", "plc/jaka_map.st")):
        with open(os.path.join(ROOT, path), "rb") as f:
            committed = f.read()
        check(committed == print_map(fmt),
              "%s is out of date: run 'make docs' and commit it" % path)


# Register mentions in the PLC docs: an abbreviation or a table's name, an
# address or a range, and the row's name in backticks when the text gives
# one ("IR 4023 `result_power_on_count`", "HR 340-359 `movel_pose_1`-`movel_tol`").
DOC_TABLES = {"ir": "input_register", "input register": "input_register",
              "input registers": "input_register", "hr": "holding_register",
              "holding register": "holding_register", "holding registers": "holding_register",
              "di": "discrete_input", "discrete input": "discrete_input",
              "discrete inputs": "discrete_input", "coil": "coil", "coils": "coil"}
DOC_MENTION = re.compile(
    r"\b(IR|HR|DI|[Cc]oils?|[Ii]nput registers?|[Hh]olding registers?|[Dd]iscrete inputs?)"
    r"\s+(\d+)(?:-(\d+))?(?:\s+`(\w+)`(?:(?:-|\.\.)`(\w+)`)?)?(\s+unassigned)?")


def register_mentions(text):
    """(line, table, first, last or None, name or None, last name or None,
    marked unassigned) for every register mention in 'text'."""
    out = []
    for m in DOC_MENTION.finditer(text):  # a mention may wrap onto the next line
        table = DOC_TABLES[re.sub(r"\s+", " ", m.group(1)).lower()]
        out.append((text.count("\n", 0, m.start()) + 1, table, int(m.group(2)),
                    int(m.group(3)) if m.group(3) else None, m.group(4), m.group(5),
                    bool(m.group(6))))
    return out


def doc_address_errors(path, rows):
    """What a doc says about addresses that the map contradicts."""
    by_name = {(r["table"], r["name"]): r for r in rows}
    starts = {(r["table"], int(r["address"])): r for r in rows}
    covered = set()
    for r in rows:
        for a in range(int(r["address"]), int(r["address"]) + int(r["count"])):
            covered.add((r["table"], a))
    errors = []
    with open(path) as f:
        text = f.read()
    mentions = register_mentions(text)
    for line, table, first, last, name, last_name, unassigned in mentions:
        where = "%s:%d: %s %d" % (os.path.basename(path), line, table, first)
        if unassigned:
            if (table, first) in covered:
                errors.append(where + " is said to be unassigned, but the map assigns it")
            continue
        if name:
            row = by_name.get((table, name))
            if not row:
                errors.append("%s: no %s named %s" % (where, table, name))
                continue
            if int(row["address"]) != first:
                errors.append("%s: %s is at %s" % (where, name, row["address"]))
            end_row = by_name.get((table, last_name)) if last_name else row
            if last_name and not end_row:
                errors.append("%s: no %s named %s" % (where, table, last_name))
                continue
            end = int(end_row["address"]) + int(end_row["count"]) - 1
            if last is not None and last != end:
                errors.append("%s-%d: the block %s ends at %d" % (where, last, name, end))
        else:
            if (table, first) not in starts:
                errors.append("%s: no row starts there" % where)
            if last is not None and (table, last) not in covered:
                errors.append("%s-%d: the map has nothing at %d" % (where, last, last))
    return mentions, errors


def test_guide_addresses_agree_with_the_map():
    """Every register the PLC guide's recipes and docs/commands.md name is
    where the map puts it: a named row at its address, a block from its
    first to its last register, an unnamed address at the start of a row."""
    rows = list(csv.DictReader(io.StringIO(print_map("csv").decode())))
    total = 0
    errors = []
    for doc in ("plc-guide.md", "commands.md"):
        mentions, found = doc_address_errors(os.path.join(ROOT, "docs", doc), rows)
        total += len(mentions)
        errors += found
    check(not errors, "%d wrong:\n  %s" % (len(errors), "\n  ".join(errors)))
    check(total >= 150, "only %d register mentions read: the pattern missed the guide" % total)
    # The pattern catches a wrong address: the same guide with joint_move's
    # count one register off fails.
    wrong = os.path.join(tempfile.mkdtemp(prefix="jakagw-guide-"), "plc-guide.md")
    with open(os.path.join(ROOT, "docs", "plc-guide.md")) as f:
        text = f.read()
    with open(wrong, "w") as f:
        mutated = re.sub(r"IR 4455(\s+)`result_joint_move_count`",
                         r"IR 4454\1`result_joint_move_count`", text)
        check(mutated != text, "the guide names IR 4455 result_joint_move_count no more")
        f.write(mutated)
    check(doc_address_errors(wrong, rows)[1], "a wrong address not caught")
    print("  %d register mentions checked" % total)


def test_bad_flags_and_config_exit_2():
    cases = [
        (["--modbus-port", "99999"], "--modbus-port: 99999 is out of range 1..65535"),
        (["--status-port", "x"], "--status-port: 'x' is not a whole number"),
        (["--print-map", "xml"], "--print-map: 'xml' must be csv, md or st"),
        (["--bogus"], "see jakagw --help"),
        (["-c", "/nonexistent.conf"], "/nonexistent.conf: cannot open"),
        (["extra"], "unexpected argument 'extra'"),
    ]
    for args, message in cases:
        r = jakagw(*args)
        check(r.returncode == 2, "%s: exit %d, expected 2" % (args, r.returncode))
        lines = [l for l in r.stderr.splitlines() if l.startswith("jakagw:")]
        check(lines and message in lines[-1], "%s: stderr %r lacks %r" % (args, r.stderr, message))
    conf = "/tmp/jakagw-cli-%d.conf" % os.getpid()
    with open(conf, "w") as f:
        f.write("[modbus]\nmax_clients = 0\n")
    r = jakagw("-c", conf, "--check-config")
    os.unlink(conf)
    check(r.returncode == 2 and ":2: [modbus] max_clients: 0 is out of range 1..1024" in r.stderr,
          "bad config file: %r" % r.stderr)


def one_line_exit_2(args, message, what=None):
    """jakagw refuses with exit code 2 and exactly one line naming the problem."""
    try:
        r = jakagw(*args)
    except subprocess.TimeoutExpired:
        raise TestFailure("%s: still running after 10 s" % (what or args))
    check(r.returncode == 2, "%s: exit %d, expected 2; stderr %r"
          % (what or args, r.returncode, r.stderr))
    lines = r.stderr.splitlines()
    check(len(lines) == 1 and message in lines[0],
          "%s: stderr %r is not one line with %r" % (what or args, r.stderr, message))


def test_bad_flags_print_one_line():
    cases = [
        (["--bogus"], "jakagw: unknown flag '--bogus'; see jakagw --help"),
        (["-x"], "jakagw: unknown flag '-x'"),
        (["--status-port"], "jakagw: --status-port needs a value"),
        (["--check-config", "-c"], "jakagw: -c needs a value"),
        (["--check-config=yes"], "--check-config takes no value"),
        (["--modbus", "1502"], "'--modbus' is ambiguous"),
    ]
    for args, message in cases:
        one_line_exit_2(args, message)


def test_control_bytes_in_a_value_or_flag_are_escaped():
    """A configuration value or a flag holding ESC, CR and VT gets exactly
    one line, with those bytes shown as \\xNN: nothing repaints the
    terminal, nothing starts a second line; valid UTF-8 reads as it is."""
    with tempfile.NamedTemporaryFile("wb", suffix=".conf", delete=False) as f:
        f.write(b"[robot]\nhost = a\x1b[31mRED\x0bX\rY\n")
    try:
        r = subprocess.run([JAKAGW, "-c", f.name, "--check-config"], capture_output=True,
                           timeout=10)
    finally:
        os.unlink(f.name)
    check(r.returncode == 2, "exit %d" % r.returncode)
    check(r.stderr.count(b"\n") == 1 and not any(b in r.stderr for b in b"\x1b\x0b\r"),
          "not one clean line: %r" % r.stderr)
    check(b"'a\\x1b[31mRED\\x0bX\\x0dY' is not an IP address" in r.stderr,
          "the value is not shown escaped: %r" % r.stderr)
    r = subprocess.run([JAKAGW, "-c", "/dev/null", "--robot-host", "a\x1b[2J\rb",
                        "--check-config"], capture_output=True, timeout=10)
    check(r.returncode == 2 and r.stderr ==
          b"jakagw: --robot-host: 'a\\x1b[2J\\x0db' is not an IP address or a host name\n",
          "flag: exit %d, %r" % (r.returncode, r.stderr))
    # A flag that is not one: its name is outside text too, in either program.
    for prog in (JAKAGW, JAKASIM):
        r = subprocess.run([prog, "--\x1b]0;owned\x07"], capture_output=True, timeout=10)
        check(r.stderr.count(b"\n") == 1 and b"\x1b" not in r.stderr and
              b"\\x1b]0;owned\\x07" in r.stderr, "%s: %r" % (prog, r.stderr))
    # --check-config prints the effective settings escaped as well.
    with tempfile.NamedTemporaryFile("wb", suffix=".conf", delete=False) as f:
        f.write("[modbus]\nwrite_allow = 127.0.0.1\n".encode())
    try:
        r = subprocess.run([JAKAGW, "-c", f.name, "--check-config"], capture_output=True,
                           timeout=10)
    finally:
        os.unlink(f.name)
    check(r.returncode == 0 and b"write_allow = 127.0.0.1\n" in r.stdout, "%r" % r.stdout)


def test_config_directory_is_refused():
    with tempfile.TemporaryDirectory() as d:
        one_line_exit_2(["-c", d, "--check-config"], "%s: is a directory" % d)
        # The daemon itself, on a port of its own: it used to start on defaults.
        one_line_exit_2(["-c", d, "--modbus-bind", "127.0.0.1",
                         "--modbus-port", str(free_port())], "%s: is a directory" % d)


def write_conf(data):
    conf = "/tmp/jakagw-cli-%d.conf" % os.getpid()
    with open(conf, "wb") as f:
        f.write(data)
    return conf


def test_check_config_refuses_what_the_daemon_would():
    """Each of these passed --check-config (exit 0), or named the wrong line
    or no key; the daemon then failed at start, or ran on a wrong value."""
    cases = [
        (b"[modbus]\nbind = not-an-ip\n",
         ":2: [modbus] bind: 'not-an-ip' is not an IPv4 or IPv6 address"),
        (b"[modbus]\nbind = 999.1.1.1\n",
         ":2: [modbus] bind: '999.1.1.1' is not an IPv4 or IPv6 address"),
        (b"[robot]\nhost = 999.1.1.1\n",
         ":2: [robot] host: '999.1.1.1' is not an IP address or a host name"),
        (b"[robot]\nhost = " + b"h" * 300 + b"\n",
         ":2: [robot] host: the line is longer than"),
        (b"[modbus\nport = 1502\n", ":1: '[modbus': a [section] line must end with ']'"),
        (b"[modbus]\nport = 15\x00 02\n", ":2: [modbus] port: the line contains a NUL byte"),
        (b"[modbus]\nport = 1502\nport = 1503\n",
         ":3: [modbus] port: duplicate key, first set on line 2"),
        (b"[robot]\nmax_document_bytes = 262145\n",
         ":2: [robot] max_document_bytes: 262145 is out of range 65536..262144"),
    ]
    for data, message in cases:
        conf = write_conf(data)
        try:
            one_line_exit_2(["-c", conf, "--check-config"], conf + message, data[:40])
        finally:
            os.unlink(conf)
    one_line_exit_2(["--modbus-bind", "not-an-ip", "--check-config"],
                    "jakagw: --modbus-bind: 'not-an-ip' is not an IPv4 or IPv6 address")


def test_check_config_says_when_no_file_was_read():
    if os.path.exists("/etc/jakagw/jakagw.conf"):
        print("  /etc/jakagw/jakagw.conf exists: not tested")
        return
    r = jakagw("--check-config")
    check(r.returncode == 0, "exit %d: %s" % (r.returncode, r.stderr))
    first = r.stdout.splitlines()[0]
    check(first.startswith(";") and "no configuration file was read" in first
          and "defaults" in first, "first line %r" % first)
    r = jakagw("-c", os.path.join(ROOT, "config", "jakagw.conf"), "--check-config")
    check(r.returncode == 0 and "no configuration file" not in r.stdout, r.stdout)


def test_check_config_prints_the_effective_settings():
    r = jakagw("-c", os.path.join(ROOT, "config", "jakagw.conf"), "--modbus-port", "1502",
               "--check-config")
    check(r.returncode == 0, "exit %d: %s" % (r.returncode, r.stderr))
    check("[modbus]" in r.stdout and "port = 1502" in r.stdout, r.stdout)
    check("word_order = high_first" in r.stdout, r.stdout)


def test_version_and_help():
    r = jakagw("--version")
    check(r.returncode == 0 and r.stdout.startswith("jakagw 0.1.0"), r.stdout)
    r = jakagw("--help")
    check(r.returncode == 0 and "--print-map" in r.stdout, r.stdout)
    r = subprocess.run([JAKASIM, "--profile", "nope"], capture_output=True, text=True)
    check(r.returncode == 2 and "must be manual, zu5s or full" in r.stderr, r.stderr)


def test_port_in_use_is_a_clear_runtime_failure():
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        r = subprocess.run([JAKAGW, "-c", "/dev/null", "--modbus-bind", "127.0.0.1",
                            "--modbus-port", str(port), "--robot-host", "127.0.0.1",
                            "--status-port", "1", "--command-port", "1"],
                           capture_output=True, text=True, timeout=10)
    check(r.returncode == 1, "exit %d" % r.returncode)
    check("cannot listen on 127.0.0.1 port %d: address already in use" % port in r.stderr,
          r.stderr)


def test_systemd_notify_ready_status_watchdog():
    """What systemd sees over NOTIFY_SOCKET: READY=1 once serving, a STATUS=
    naming the link states, WATCHDOG=1 pings, STOPPING=1 on SIGTERM."""
    import socket
    import tempfile
    from harness import Gateway, Sim
    d = tempfile.mkdtemp()
    path = os.path.join(d, "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5)
    sim = Sim()
    gw = None
    try:
        gw = Gateway(sim, env={"NOTIFY_SOCKET": path, "WATCHDOG_USEC": "400000"})
        messages = []

        def receive_until(text):
            while not any(text in m for m in messages):
                messages.append(sock.recv(4096).decode())
            return True
        receive_until("READY=1")
        check(any("STATUS=status link" in m for m in messages), "no STATUS=: %r" % messages)
        receive_until("WATCHDOG=1")
        receive_until("status link connected")
        gw.stop()
        gw = None
        receive_until("STOPPING=1")
    finally:
        if gw:
            gw.stop()
        sim.stop()
        sock.close()
        os.unlink(path)
        os.rmdir(d)


def test_every_source_file_carries_its_licence():
    """LICENSE is MIT; each file under src/, include/, sim/ and tests/ (and
    the fuzz targets, the bench, the scripts) starts with its SPDX line,
    after a #! line if it has one; a JSON file, which cannot hold a comment,
    has it in FILE.license beside it."""
    with open(os.path.join(ROOT, "LICENSE")) as f:
        check(f.readline().strip() == "MIT License", "LICENSE is not the MIT licence")
    with open(os.path.join(ROOT, "debian", "copyright")) as f:
        copyright = f.read()
    check("License: MIT" in copyright and "all rights reserved" not in copyright.lower(),
          "debian/copyright does not grant the MIT licence")
    missing = []
    checked = 0
    for top in ("src", "sim", "tests", "fuzz", "bench", "scripts"):
        for d, dirs, files in os.walk(os.path.join(ROOT, top)):
            dirs[:] = [x for x in dirs if x not in ("seeds", "__pycache__")]
            for name in files:
                path = os.path.join(d, name)
                if name.endswith(".license") or name.endswith(".pyc"):
                    continue
                checked += 1
                if name.endswith(".json"):
                    ok = os.path.exists(path + ".license")
                else:
                    with open(path, encoding="utf-8", errors="replace") as f:
                        head = [f.readline(), f.readline()]
                    first = head[1] if head[0].startswith("#!") else head[0]
                    ok = "SPDX-License-Identifier: MIT" in first
                if not ok:
                    missing.append(os.path.relpath(path, ROOT))
    check(checked > 90, "only %d files found" % checked)
    check(not missing, "no SPDX line at the top of: %s" % ", ".join(sorted(missing)))


if __name__ == "__main__":
    run([test_every_source_file_carries_its_licence, test_committed_register_map_is_current,
         test_guide_addresses_agree_with_the_map, test_bad_flags_and_config_exit_2,
         test_bad_flags_print_one_line, test_control_bytes_in_a_value_or_flag_are_escaped,
         test_config_directory_is_refused,
         test_check_config_refuses_what_the_daemon_would,
         test_check_config_says_when_no_file_was_read,
         test_check_config_prints_the_effective_settings, test_version_and_help,
         test_port_in_use_is_a_clear_runtime_failure,
         test_systemd_notify_ready_status_watchdog])
