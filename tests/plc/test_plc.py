#!/usr/bin/python3
# SPDX-License-Identifier: MIT
"""The PLC library as a PLC (make test-plc): builds matiec from its
tarball (tests/plc/matiec.sh, cached), compiles every .st file of plc/
with iec2c, compiles the library and tests/plc/cell.st to C and links it
into the scan-cycle harness (tests/plc/plc_scan.c), runs the blocks' unit
tests against a simulated image, then each end-to-end case against a real
jakagw in front of a real jakasim. One line per case, then
"N passed, N failed".

Without the tarball: a failure under CI=true, a skip (exit 0, no count)
elsewhere. MATIEC_TARBALL names another tarball."""
import os
import hashlib
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "integration"))
from harness import Gateway, Sim, check, wait_until  # noqa: E402

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
BUILD = os.path.join(ROOT, os.environ.get("JAKAGW_BIN_DIR", "build"))
OUT = os.path.join(BUILD, "plc")
MAP = os.path.join(ROOT, "plc", "jaka_map.st")
LIB = os.path.join(ROOT, "plc", "jaka.st")
EXAMPLE = os.path.join(ROOT, "plc", "examples", "jaka_cell.st")
PICK_PLACE = os.path.join(ROOT, "tests", "plc", "pick_place.st")
EXAMPLES = os.path.join(ROOT, "plc", "examples")

GATEWAY_CONFIG = """
[commands]
motion = true
[network_exception]
time_limit_ms = 500
motion_enable = true
"""

results = []


def line(ok, name, text):
    results.append(ok)
    print("%s %s%s" % ("PASS" if ok else "FAIL", name, text), flush=True)


def map_parts():
    """The map's TYPE block and its VAR_GLOBAL CONSTANT block: a strict
    IEC 61131-3 compiler takes the second inside a CONFIGURATION."""
    text = open(MAP).read()
    types = re.search(r"^TYPE\n.*?^END_TYPE\n", text, re.M | re.S).group(0)
    return types, re.search(r"^VAR_GLOBAL CONSTANT\n.*?^END_VAR\n", text, re.M | re.S).group(0)


def unit_source(program_files, program_type, extra=""):
    """One compilation unit: the map's types, the library, the programs,
    and a configuration with the map's constants and one 10 ms task
    running program_type as Main (and 'extra' program lines)."""
    types, globals_ = map_parts()
    body = "".join(open(f).read() + "\n" for f in program_files)
    return (types + open(LIB).read() + "\n" + body +
            "CONFIGURATION Cell\n" + globals_ +
            "RESOURCE Res ON PLC\n  TASK Scan(INTERVAL := T#10ms, PRIORITY := 0);\n"
            "  PROGRAM Main WITH Scan : %s;\n%sEND_RESOURCE\nEND_CONFIGURATION\n"
            % (program_type, extra))


def iec2c(matiec, source, outdir):
    os.makedirs(outdir, exist_ok=True)
    path = os.path.join(outdir, "unit.st")
    with open(path, "w") as f:
        f.write(source)
    r = subprocess.run([os.path.join(matiec, "iec2c"), "-I", os.path.join(matiec, "lib"),
                        "-T", outdir, path], capture_output=True, text=True)
    return r.returncode == 0, (r.stdout + r.stderr).strip()


def compile_checks(matiec):
    """Every .st file under plc/ through iec2c: the map in a configuration,
    the library with the map's types, each example program with both."""
    ok, out = iec2c(matiec, unit_source([], "JakaEmpty").replace(
        "CONFIGURATION Cell", "PROGRAM JakaEmpty\nVAR\n  X : BOOL;\nEND_VAR\nX := TRUE;\n"
        "END_PROGRAM\nCONFIGURATION Cell"), os.path.join(OUT, "check-lib"))
    line(ok, "iec2c plc/jaka_map.st and plc/jaka.st", "" if ok else ": " + out[-2000:])
    for dirpath, _, files in sorted(os.walk(os.path.join(ROOT, "plc"))):
        for name in sorted(files):
            path = os.path.join(dirpath, name)
            if not name.endswith(".st") or path in (MAP, LIB):
                continue
            program = re.search(r"^PROGRAM\s+(\w+)", open(path).read(), re.M)
            rel = os.path.relpath(path, ROOT)
            if not program:
                line(False, "iec2c " + rel, ": no PROGRAM in it")
                continue
            ok, out = iec2c(matiec, unit_source([path], program.group(1)),
                            os.path.join(OUT, "check-" + name[:-3]))
            line(ok, "iec2c " + rel, "" if ok else ": " + out[-2000:])


def build_harness(matiec):
    """The library and cell.st as C, linked with plc_scan.c and libmodbus.
    The blocks' C (Res.c, which includes POUS.c) and the harness run under
    ASan and UBSan: matiec does not check array bounds, so an index out of
    an image array would be found here. Cell.c holds only the 3000
    constants, compiled without optimisation (5 s rather than 20).

    The generated C and its objects are kept in plc-gen-KEY beside
    matiec's build (MATIEC_CACHE, which CI keeps across runs, else the
    build directory), KEY covering the source, the flags, the compiler and
    matiec: a run that changes none of them compiles only plc_scan.c."""
    # The cell (every block) as Main; the shipped example as Example, run
    # by the same task (its image is kept in step only in case "example").
    source = unit_source([os.path.join(ROOT, "tests", "plc", "cell.st"), EXAMPLE, PICK_PLACE],
                         "JakaCell", "  PROGRAM Example WITH Scan : JakaExample;\n"
                         "  PROGRAM PickPlace WITH Scan : JakaPickPlace;\n")
    includes = ["-std=gnu11"]
    san = ["-O1", "-g", "-fno-omit-frame-pointer", "-fsanitize=address,undefined",
           "-fno-sanitize-recover=all"]
    units = (("Cell", ["-O0"], "plain"), ("Res", san, "san"))
    cc = subprocess.run(["cc", "--version"], capture_output=True, text=True).stdout
    key = hashlib.sha256(repr((source, units, cc, os.path.basename(matiec))).encode()).hexdigest()[:12]
    cache = os.path.dirname(matiec)
    gen = os.path.join(cache, "plc-gen-" + key)
    objs = [os.path.join(gen, "%s-%s.o" % (name, kind)) for name, _, kind in units]
    includes += ["-isystem", gen, "-isystem", os.path.join(matiec, "lib", "C")]
    if not all(os.path.exists(o) for o in objs):
        shutil.rmtree(gen, ignore_errors=True)
        ok, out = iec2c(matiec, source, gen + ".tmp")
        check(ok, "iec2c of the library and cell.st: " + out[-2000:])
        for (name, flags, kind), obj in zip(units, objs):
            # matiec's own C: its warnings are not ours to fix.
            subprocess.run(["cc", "-std=gnu11", "-isystem", gen + ".tmp", "-isystem",
                            os.path.join(matiec, "lib", "C")] + flags +
                           ["-w", "-c", os.path.join(gen + ".tmp", name + ".c"),
                            "-o", os.path.join(gen + ".tmp", os.path.basename(obj))], check=True)
        os.rename(gen + ".tmp", gen)
        for old in os.listdir(cache):  # one generation kept
            if old.startswith("plc-gen-") and old != os.path.basename(gen):
                shutil.rmtree(os.path.join(cache, old), ignore_errors=True)
    modbus = subprocess.run(["pkg-config", "--cflags", "--libs", "libmodbus"],
                            capture_output=True, text=True, check=True).stdout.split()
    exe = os.path.join(OUT, "plc_scan")
    os.makedirs(OUT, exist_ok=True)
    subprocess.run(["cc"] + includes + san + ["-Wall", "-Wextra", "-Werror",
                                              os.path.join(ROOT, "tests", "plc", "plc_scan.c"),
                                              os.path.join(ROOT, "tests", "plc", "vendor_client.c")] +
                   objs + ["-o", exe] + modbus + ["-lm"], check=True)
    return exe


def contract_in_place():
    """Whether this jakagw has the PLC contract (result counts, motion
    state, the trigger rule), known from its configuration keys, not from
    its behaviour: a gateway that has it and breaks it fails the cases
    instead of skipping them."""
    from harness import JAKAGW
    keys = subprocess.run([JAKAGW, "--print-config-keys"], capture_output=True, text=True,
                          check=True).stdout
    return "require_heartbeat" in keys


# The cases of make test-plc; those marked need the PLC contract's result
# counts and motion state (the gateway's, not the library's).
CASES = [
    ("startup", True, "the start-up recipe: link, reset, power, override, load, play, output, stop"),
    ("moves", True, "joint, linear and TCP moves: Done after arrival, not before"),
    ("heartbeat_loss", True, "heartbeat lost during a move: CommandAborted, the arm stops"),
    ("motion_enable", True, "motion enable dropped during a move: CommandAborted"),
    ("fault_reset", True, "fault reset after a motion-enable drop, then a move"),
    ("restart", True, "the PLC restarted mid-handshake: refused, then runs"),
    ("link_lost", False, "the Modbus link lost and back: Valid falls and returns"),
    ("estop", True, "e-stop during a move: CommandAborted"),
    ("mailbox", True, "the exactly-once mailbox: one rapid_rate at the robot"),
    ("two_connections", True, "reads and writes on two connections, as a Siemens PLC makes them"),
    ("refusals", True, "a move before the heartbeat: ErrorID 16#0201 from the gateway's reason"),
    ("example", True, "plc/examples/jaka_cell.st's whole sequence, each command once at the robot"),
    ("retrigger", True, "a new Execute edge on a running move: CommandAborted, Done at the new target"),
    ("mailbox_move", True, "JAKA_Command's joint_move: Done on arrival"),
]


# ---- the vendors' set-ups, read from the shipped examples ----

FUNCTIONS = {"FC04": "ir", "FC02": "di", "FC16": "hr", "FC15": "co"}


def markdown_rows(text, header):
    """The rows of the Markdown table whose header line starts 'header'."""
    lines = text[text.index(header):].splitlines()
    rows = []
    for l in lines[2:]:
        if not l.startswith("|"):
            break
        rows.append([c.strip() for c in l.strip().strip("|").split("|")])
    return rows


def function_of(text):
    m = re.search(r"FC(0[1-6]|1[56])", text)
    check(m and m.group(0) in FUNCTIONS, "no function code in '%s'" % text)
    return FUNCTIONS[m.group(0)]


def codesys_requests():
    """plc/examples/codesys/README.md's channel table: one slave, one
    connection; each channel's function, trigger (cyclic N ms or rising
    edge of a "changed" bit), offset and length."""
    text = open(os.path.join(EXAMPLES, "codesys", "README.md")).read()
    lines = ["vendor codesys"]
    for name, access, trigger, offset, length, _ in markdown_rows(text, "| Channel | Access type"):
        cyclic = re.match(r"cyclic (\d+) ms", trigger)
        check(cyclic or trigger.startswith("rising edge"), "channel %s: trigger '%s'" % (name, trigger))
        lines.append("request 0 %s %d %d %s" % (function_of(access), int(offset), int(length),
                                                 "cyclic " + cyclic.group(1) if cyclic else "change"))
    return lines


def array_constant(text, name):
    m = re.search(r"\b%s\s*:\s*Array\s*\[[^\]]*\]\s*of\s*\w+\s*:=\s*\[([^\]]*)\]" % name, text,
                  re.I)
    check(m, "no constant %s" % name)
    return [int(v) for v in m.group(1).split(",")]


def instance_requests(vendor, text):
    """Siemens' JakaModbus.scl, TwinCAT's MB_Sync: the ranges read in turn
    by one instance (IR_FIRST/IR_COUNT, DI_FIRST/DI_COUNT), the blocks
    written by the other (HR_FIRST/HR_COUNT, the first the heartbeat), and
    the coils (CoilsSent's size) one changed coil per request."""
    lines = ["vendor " + vendor]
    for table, first, count in (("ir", "IR_FIRST", "IR_COUNT"), ("di", "DI_FIRST", "DI_COUNT")):
        for a, n in zip(array_constant(text, first), array_constant(text, count)):
            lines.append("request 0 %s %d %d turn" % (table, a, n))
    for a, n in zip(array_constant(text, "HR_FIRST"), array_constant(text, "HR_COUNT")):
        lines.append("request 1 hr %d %d turn%s" % (a, n, " heartbeat" if a == 0 else ""))
    coils = re.search(r"CoilsSent\s*:\s*Array\s*\[0\.\.(\d+)\]", text, re.I)
    check(coils, "no CoilsSent")
    lines.append("request 1 co 0 %d turn single" % (int(coils.group(1)) + 1))
    return lines


def siemens_requests():
    return instance_requests("siemens", open(os.path.join(EXAMPLES, "siemens", "JakaModbus.scl")).read())


def twincat_requests():
    text = open(os.path.join(EXAMPLES, "twincat", "README.md")).read()
    return instance_requests("twincat", text[text.index("PROGRAM MB_Sync"):])


def rockwell_requests():
    """plc/examples/rockwell/README.md's ProSoft command list: Enable 1
    continuous (every Poll Interval), 2 conditional (on change)."""
    text = open(os.path.join(EXAMPLES, "rockwell", "README.md")).read()
    m = re.search(r"Minimum Command Delay (\d+) ms", text)
    check(m, "no Minimum Command Delay")
    lines = ["vendor rockwell", "delay " + m.group(1)]
    for _, enable, interval, fc, address, count, image in markdown_rows(text, "| Cmd | Enable"):
        check(enable in ("1", "2"), "command enable '%s'" % enable)
        lines.append("request 0 %s %d %d %s%s" % (
            function_of(fc), int(address), int(count),
            "cyclic %d" % max(1, int(interval)) if enable == "1" else "change",
            " heartbeat" if "heartbeat" in image else ""))
    return lines


VENDORS = (("codesys", codesys_requests), ("siemens", siemens_requests),
           ("twincat", twincat_requests), ("rockwell", rockwell_requests))
PERIODS_MS = (1, 10, 100)
# Each cell case: the example's sequence, then 3 pick-and-place cycles.
CELL_SECONDS = 60
# A one-request-at-a-time client: 13 reads of 46 ms: each range every 600 ms.
LINK_CASE = ("siemens", 46, "link", 60)
RESTART_CASE = ("twincat", 10, "restart", 60)
# An HMI on the PLC's host changes an output and the override between the
# PLC's requests (plc_scan.c, vendor_hmi), in each set-up that writes its
# outputs on change (CODESYS's channel writes them every 10 ms: an HMI's
# change there lasts one cycle). The gateway lets the host's connections
# write (owner = host).
HMI_CASES = [(vendor, 10, "hmi", 30) for vendor in ("siemens", "twincat", "rockwell")]
HMI_CONFIG = GATEWAY_CONFIG + "owner = host\n"
# The PLC restarted mid-handshake (plc_scan.c, vendor_plc_restart): its
# load of prog_A written, then the restarted program's load of prog_B is
# refused (16#0202) and its retry runs. Siemens' client writes a coil
# when it changed: the restarted PLC's 1 meets the 1 left at the gateway
# (a client writing its coils every cycle writes the 0 first).
PLC_RESTART_CASE = ("siemens", 10, "plc_restart", 30)
# What the cell asks of the robot: set_digital_output per gripper change
# at most twice; each move once.
GRIPPER_CHANGES = {"cell": 1 + 2 * 3, "restart": 2 * 4, "link": 0, "hmi": 2 * 3, "plc_restart": 0}
# The robot commands each case asks for, exactly. "hmi", per round: the
# PLC's output, the HMI's, the PLC's again (its other level first, which
# the robot reports already: nothing sent); the PLC's override, the HMI's,
# one per mille off, the PLC's again.
COMMANDS = {"cell": {"joint_move": 1 + 2 * 3, "moveL": 3}, "restart": {"joint_move": 2 * 4, "moveL": 4},
            "link": {}, "hmi": {"set_digital_output": 2 * 3, "rapid_rate": 2 * 4},
            "plc_restart": {"load_program": 2}}
# The programs loaded, in order, where a case names them.
PROGRAMS = {"plc_restart": ["prog_A", "prog_B"]}

gateway_lock = threading.Lock()


def new_gateway(sim, port=None, config=GATEWAY_CONFIG):
    """A jakagw in front of 'sim'; on 'port' (a restart) if given."""
    import harness
    with gateway_lock:
        if port is None:
            return Gateway(sim, config)
        free = harness.free_port
        harness.free_port = lambda: port
        try:
            return Gateway(sim, config)
        finally:
            harness.free_port = free


def vendor_case(exe, vendor, lines, period, what, seconds, out):
    """One set-up at one task period, with its own jakasim and jakagw;
    appends (ok, name, text) to out."""
    name = "vendor_%s_%dms_%s" % (vendor, period, what)
    sim = Sim("--log-commands")
    gw = None
    try:
        gw = new_gateway(sim, config=HMI_CONFIG if what == "hmi" else GATEWAY_CONFIG)
        with tempfile.TemporaryDirectory(prefix="plc-vendor-") as tmp:
            requests = os.path.join(tmp, "requests")
            go = os.path.join(tmp, "go")
            with open(requests, "w") as f:
                f.write("\n".join(lines) + "\n")
            proc = subprocess.Popen([exe, "vendor", requests, str(gw.modbus_port), str(sim.proc.pid),
                                     str(period), what, str(seconds), go],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            err = []
            reader = threading.Thread(target=lambda: err.append(proc.stderr.read()))
            reader.start()
            result = []
            for l in proc.stdout:
                if l.strip() == "PAUSED":
                    # The gateway restarts on the same port; the PLC goes on.
                    port = gw.modbus_port
                    gw.stop()
                    gw = new_gateway(sim, port)
                    open(go, "w").close()
                else:
                    result.append(l.rstrip())
            proc.wait(timeout=seconds + 120)
            reader.join()
        text = result[-1] if result else "no output; stderr: " + "".join(err)[-1500:]
        ok = proc.returncode == 0 and text.startswith("PASS")
        if ok:
            sent = sim_commands_named(sim, None)
            outputs = sum(1 for c in sent if c.get("cmdName") == "set_digital_output")
            bad = []
            if outputs > 2 * GRIPPER_CHANGES[what]:
                bad.append("%d set_digital_output for %d gripper changes" % (outputs, GRIPPER_CHANGES[what]))
            for command, n in COMMANDS[what].items():
                got = sum(1 for c in sent if c.get("cmdName") == command)
                if got != n:
                    bad.append("%d %s at the robot, the cell asked %d" % (got, command, n))
            loaded = [c.get("programName") for c in sent if c.get("cmdName") == "load_program"]
            if what in PROGRAMS and loaded != PROGRAMS[what]:
                bad.append("the robot loaded %s, the cell asked %s" % (loaded, PROGRAMS[what]))
            if bad:
                ok = False
                text += "; " + ", ".join(bad)
            elif what in PROGRAMS:
                text += "; the robot loaded %s" % ", ".join(loaded)
            else:
                text += "; the robot received %d set_digital_output for %d changes" % (
                    outputs, GRIPPER_CHANGES[what])
        text = re.sub(r"^(PASS|FAIL) \S+ \d+ ms \S+:? ?", "", text)
        if not ok:
            log = gw.stop()
            gw = None
            text += "\n" + "".join(err)[-1000:] + "\njakagw:\n" + log[-1500:]
        out.append((ok, name, " " + text if ok else ": " + text))
    except Exception as e:  # a case's harness failure is its failure, not the run's
        out.append((False, name, ": %s" % e))
    finally:
        if gw:
            gw.stop()
        sim.stop()


def vendor_cases(exe, only):
    """Every vendor's set-up at every task period, side by side (one
    jakasim, jakagw and PLC process each), with the one-request-at-a-time
    link case, a gateway restart and the HMI cases. 'only': "vendor" runs
    them all, "vendor_WHAT" the cases of one kind (vendor_hmi)."""
    runs = []
    for vendor, requests in VENDORS:
        lines = requests()
        for period in PERIODS_MS:
            runs.append((vendor, lines, period, "cell", CELL_SECONDS))
    build = dict(VENDORS)
    for vendor, period, what, seconds in [LINK_CASE, RESTART_CASE, PLC_RESTART_CASE] + HMI_CASES:
        runs.append((vendor, build[vendor](), period, what, seconds))
    if only and "vendor" not in only:
        runs = [r for r in runs if "vendor_" + r[3] in only]
    out = []
    threads = [threading.Thread(target=vendor_case, args=(exe,) + r + (out,)) for r in runs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for ok, name, text in sorted(out, key=lambda r: r[1]):
        line(ok, name, text)


def run_case(exe, name, needs_contract, contract):
    if needs_contract and not contract:
        print("SKIP %s: needs the PLC contract (this jakagw has no [network_exception] "
              "require_heartbeat)" % name, flush=True)
        return
    sim = Sim("--log-commands")
    gw = None
    try:
        gw = Gateway(sim, GATEWAY_CONFIG)
        args = [exe, "case", name, str(gw.modbus_port), str(sim.proc.pid)]
        if name == "two_connections":
            args.append("split")
        r = subprocess.run(args, capture_output=True, text=True, timeout=120)
        out = r.stdout.strip().splitlines()
        ok = r.returncode == 0 and out and out[-1].startswith("PASS")
        if ok and name == "mailbox":
            rates = [c for c in sim_commands_named(sim, "rapid_rate")]
            ok = len(rates) == 1
            if not ok:
                out.append("FAIL mailbox: jakasim received %d rapid_rate, expected 1" % len(rates))
        if ok and name == "example":
            sent = [c["cmdName"] for c in sim_commands_named(sim, None)
                    if not is_housekeeping(c.get("cmdName"))]
            want = ["power_on", "enable_robot", "rapid_rate", "load_program", "play_program",
                    "set_digital_output", "stop_program", "joint_move"]
            ok = sent == want and any(c.get("programName") == "pick_and_place"
                                      for c in sim_commands_named(sim, "load_program"))
            if not ok:
                out.append("FAIL example: jakasim received %s, expected %s" % (sent, want))
        if ok and name == "restart":
            stops = sim_commands_named(sim, "stop_program")
            ok = len(stops) == 2
            if not ok:
                out.append("FAIL restart: jakasim received %d stop_program, expected 2 "
                           "(the first request and the retry; none for the refused one)" % len(stops))
        text = out[-1] if out else "no output; stderr: " + r.stderr[-1500:]
        text = re.sub(r"^(PASS|FAIL) %s:? ?" % name, "", text)
        line(ok, name, " " + text if ok else ": " + "\n".join(out[-3:]) + "\n" + r.stderr[-1500:])
    finally:
        if gw:
            gw.stop()
        sim.stop()


def sim_commands_named(sim, name):
    from harness import sim_commands
    return sim_commands(sim, name)


def is_housekeeping(name):
    from harness import is_housekeeping as housekeeping
    return housekeeping(name)


def main():
    start = time.monotonic()
    r = subprocess.run([os.path.join(ROOT, "tests", "plc", "matiec.sh"), BUILD],
                       capture_output=True, text=True)
    sys.stderr.write(r.stderr)
    if r.returncode == 77:
        if os.environ.get("CI") == "true":
            print("FAIL matiec: no source tarball (MATIEC_TARBALL); CI must have it")
            print("0 passed, 1 failed")
            return 1
        print("SKIP make test-plc: no matiec source tarball (MATIEC_TARBALL)")
        return 0
    if r.returncode != 0:
        print("FAIL matiec: the build failed")
        print("0 passed, 1 failed")
        return 1
    matiec = r.stdout.strip().splitlines()[-1]
    t_matiec = time.monotonic() - start
    compile_checks(matiec)
    exe = build_harness(matiec)
    t_build = time.monotonic() - start
    u = subprocess.run([exe, "unit"], capture_output=True, text=True, timeout=120)
    for l in u.stdout.splitlines():
        m = re.match(r"^(PASS|FAIL) (\S+)(.*)$", l)
        if m:
            line(m.group(1) == "PASS", m.group(2), m.group(3))
    if u.returncode != 0 and "FAIL" not in u.stdout:
        line(False, "unit", ": exit %d %s" % (u.returncode, u.stderr[-1500:]))
    contract = contract_in_place()
    only = os.environ.get("PLC_CASES")  # e.g. "vendor", "vendor_hmi" or "moves,example"
    t_vendor = time.monotonic()
    wanted = only.split(",") if only else []
    if contract and (not only or any(w.startswith("vendor") for w in wanted)):
        vendor_cases(exe, wanted)
    t_vendor = time.monotonic() - t_vendor
    for name, needs, _ in CASES:
        if not only or name in only.split(","):
            run_case(exe, name, needs, contract)
    print("times: matiec %.1f s (cached when under 1 s), compile and link %.1f s, vendor cases "
          "%.1f s, total %.1f s" % (t_matiec, t_build - t_matiec, t_vendor, time.monotonic() - start))
    passed = sum(1 for ok in results if ok)
    failed = len(results) - passed
    print("%d passed, %d failed" % (passed, failed))
    return 1 if failed else 0


if __name__ == "__main__":
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    sys.exit(main())
