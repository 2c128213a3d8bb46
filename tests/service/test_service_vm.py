#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The installed service as a plant runs it: the Debian package from 'make
deb', installed by apt into a Debian 12 image (scripts/make-service-image.py),
under real systemd as PID 1, in a VM booted by qemu with this machine's
Debian kernel and its stock initrd (KVM when /dev/kvm opens, TCG
otherwise). One boot serves every case.

  tests/service/test_service_vm.py [BUILD_DIR]      (make test-service)

The host drives the VM through a test agent on a virtio serial port
(tests/service/agent.py): shell commands and Python (pymodbus) run inside,
their output comes back. Everything is checked from outside the gateway:
what the robot (jakasim, robot.service) received, what a Modbus master
reads, and systemd's own view (systemctl show, journalctl -o json). The
RTU case's master runs on this machine, on the host side of the VM's
serial ports (a pty behind /dev/ttyS1, another behind a USB serial
adapter). The console (ttyS0) is kept in BUILD/service-vm/console.log.

Needs root (mmdebstrap), qemu-system-x86, mbpoll, and this machine's
/boot/vmlinuz with its initrd: 'make deps' installs them.
JAKAGW_SERVICE_DEB=PATH uses that package instead of running make deb.
"""
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else
                        os.environ.get("JAKAGW_BIN_DIR", os.path.join(ROOT, "build")))
os.environ.setdefault("JAKAGW_BIN_DIR", BUILD)
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))
from harness import TestFailure, check, run, wait_until, SIM_COMMAND_MARK  # noqa: E402

VMDIR = os.path.join(BUILD, "service-vm")
MAGIC = 0x4A4B
# The register map, as the installed jakagw prints it (case_boot).
ADDR = {}
COIL_POWER_ON = IR_INTERP = IR_HANDLE = None
PAUSED, RUNNING = 2, 3
WATCHDOG_S, RESTART_S = 10, 2   # the units' WatchdogSec= and RestartSec=
FIGURES = []                    # (case, text) for the closing summary
state = {}


def figure(text):
    print("  " + text, flush=True)
    FIGURES.append(text)


class Vm:
    """qemu with the image, and the agent's channel."""

    def __init__(self, image, kernel, initrd):
        self.dir = VMDIR
        self.sock_path = os.path.join(self.dir, "agent.sock")
        self.console = os.path.join(self.dir, "console.log")
        for p in (self.sock_path, self.console):
            if os.path.exists(p):
                os.remove(p)
        self.kvm, self.kvm_why = kvm_usable(kernel)
        accel = ["-accel", "kvm", "-cpu", KVM_CPU] if self.kvm else ["-accel", "tcg"]
        # For speed under TCG, none of which a case looks at: no default
        # devices (the floppy, CD-ROM and VGA cost the kernel and udev
        # seconds to probe); the disk's flushes not passed to this machine
        # (a snapshot, thrown away); norandmaps: every process maps its
        # libraries where the last one did, so TCG reuses its translated
        # code instead of translating perl, python and systemctl again for
        # each of the hundreds of processes the cases start; tsc=reliable:
        # the clock read in the vDSO from the TSC (which TCG derives from
        # this machine's), not by a system call and an emulated HPET read
        # (the kernel takes a 2-CPU AMD-model TSC as unsynchronised);
        # mitigations=off: no Spectre sequences (retpolines, RSB fills) for
        # TCG to emulate in every system call and context switch (10 % of
        # qemu's CPU time and of the maintainer scripts' in one measure).
        # No -no-reboot: a case that reboots the guest (both_enabled) keeps
        # the same qemu, whose snapshot keeps what the cases wrote.
        argv = ["qemu-system-x86_64"] + accel + [
            "-nodefaults", "-m", "1024", "-smp", "2", "-display", "none", "-monitor", "none",
            "-nic", "none",
            "-kernel", kernel, "-initrd", initrd,
            "-append", "root=/dev/vda rw console=ttyS0 loglevel=4 audit=1 net.ifnames=0 "
                       "systemd.show_status=0 panic=-1 norandmaps tsc=reliable mitigations=off",
            "-drive", "file=%s,format=raw,if=virtio,snapshot=on,cache=unsafe" % image,
            # ttyS0: the console, into a file; ttyS1: the RTU line, a pty.
            "-chardev", "file,id=con,path=%s" % self.console, "-serial", "chardev:con",
            "-chardev", "pty,id=rtu", "-serial", "chardev:rtu",
            # A USB serial adapter (FTDI, as qemu models it) on its own pty.
            "-device", "qemu-xhci", "-chardev", "pty,id=usbser",
            "-device", "usb-serial,chardev=usbser",
            "-device", "virtio-serial-pci",
            "-chardev", "socket,id=agent,path=%s,server=on,wait=off" % self.sock_path,
            "-device", "virtserialport,chardev=agent,name=jakagw.agent"]
        self.stderr_path = os.path.join(self.dir, "qemu.log")
        self.stderr = open(self.stderr_path, "w")
        self.start = time.monotonic()
        self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=self.stderr,
                                     stderr=subprocess.STDOUT)
        self.sock = None
        state["vm"] = self  # stopped at the end whatever happens next
        self.ptys = {}
        deadline = time.monotonic() + 30
        while len(self.ptys) < 2 or not os.path.exists(self.sock_path):
            check(self.proc.poll() is None, "qemu exited: %s" % self.qemu_log())
            check(time.monotonic() < deadline, "qemu did not start: %s" % self.qemu_log())
            for m in re.finditer(r"char device redirected to (\S+) \(label (\w+)\)",
                                 self.qemu_log()):
                self.ptys[m.group(2)] = m.group(1)
            time.sleep(0.05)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        while True:  # the socket file comes a moment before qemu listens
            try:
                self.sock.connect(self.sock_path)
                break
            except ConnectionRefusedError:
                check(time.monotonic() < deadline, "qemu does not listen on the agent socket")
                time.sleep(0.05)
        self.buf = b""
        self.next_id = 1
        hello = self._read_line(240, "the agent's hello (the VM's boot)")
        self.boot_s = time.monotonic() - self.start
        self.hello_uptime = hello["hello"]

    def reboot(self):
        """systemctl reboot, then the agent's hello from the next boot (in
        the same qemu); the Python preludes the cases use are loaded again.
        Returns the seconds from the request to the hello."""
        start = time.monotonic()
        # Forced (-f): the units are not stopped one by one, which nothing
        # checks and which took half of each reboot under TCG; the file
        # systems are synced and unmounted as in any reboot.
        self.sock.sendall((json.dumps({"id": 0, "sh": "systemctl reboot -f"}) + "\n").encode())
        while "hello" not in self._read_line(240, "the agent's hello after a reboot"):
            pass
        for code in state["preludes"]:
            self.py(code)
        return time.monotonic() - start

    def qemu_log(self):
        with open(self.stderr_path, errors="replace") as f:
            return f.read()

    def console_text(self):
        try:
            with open(self.console, errors="replace") as f:
                return f.read()
        except OSError:
            return ""

    def _read_line(self, timeout, what):
        deadline = time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = deadline - time.monotonic()
            if left <= 0 or self.proc.poll() is not None:
                raise TestFailure("no answer from the VM for %s (qemu %s); console:\n%s"
                                  % (what, "exited" if self.proc.poll() is not None
                                     else "running", self.console_text()[-3000:]))
            self.sock.settimeout(min(left, 1.0))
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                continue
            check(chunk, "the agent's channel closed")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return json.loads(line)

    def _call(self, req, timeout):
        req["id"] = self.next_id
        req["timeout"] = timeout
        self.next_id += 1
        self.sock.sendall((json.dumps(req) + "\n").encode())
        while True:
            reply = self._read_line(timeout + 30, req.get("sh") or "python")
            if reply.get("id") == req["id"]:
                return reply

    def sh(self, cmd, timeout=60, ok=(0,)):
        """A shell command in the VM: its stdout (a bad exit fails)."""
        r = self._call({"sh": cmd}, timeout)
        if ok is not None and r["rc"] not in ok:
            raise TestFailure("in the VM: %s: exit %d\n%s%s" % (cmd, r["rc"], r["out"][-3000:],
                                                                r["err"][-3000:]))
        return r["out"]

    def rc(self, cmd, timeout=60):
        r = self._call({"sh": cmd}, timeout)
        return r["rc"], r["out"] + r["err"]

    def py(self, code, timeout=60):
        """Python in the VM's agent: the value it leaves in 'result'."""
        r = self._call({"py": code}, timeout)
        if r["rc"] != 0:
            raise TestFailure("in the VM (python): %s" % r["err"][-3000:])
        return r["out"]

    def write(self, path, text, mode=0o644):
        self.py("import os\nwith open(%r, 'w') as f:\n    f.write(%r)\nos.chmod(%r, %d)"
                % (path, text, path, mode))

    def stop(self):
        if self.proc.poll() is None and self.sock is not None:
            try:
                self.sock.sendall((json.dumps({"id": 0, "sh": "systemctl poweroff"}) +
                                   "\n").encode())
                self.proc.wait(timeout=30)
            except (OSError, subprocess.TimeoutExpired):
                pass
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        if self.sock is not None:
            self.sock.close()
        self.stderr.close()


KVM_CPU = "host,-arch-capabilities"


def kvm_usable(kernel):
    """Whether KVM runs this kernel: /dev/kvm opens, and a probe boot prints
    the kernel's first line within a few seconds. (A nested KVM, as on some
    cloud machines, may open and then hang the guest after decompression.)
    JAKAGW_SERVICE_ACCEL=kvm or tcg skips the probe."""
    forced = os.environ.get("JAKAGW_SERVICE_ACCEL")
    if forced in ("kvm", "tcg"):
        return forced == "kvm", "JAKAGW_SERVICE_ACCEL=" + forced
    try:
        fd = os.open("/dev/kvm", os.O_RDWR)
    except OSError as e:
        return False, "/dev/kvm: %s" % e.strerror
    os.close(fd)
    proc = subprocess.Popen(["qemu-system-x86_64", "-accel", "kvm", "-cpu", KVM_CPU, "-m", "256",
                             "-display", "none", "-monitor", "none", "-nic", "none",
                             "-no-reboot", "-kernel", kernel, "-serial", "stdio",
                             "-append", "console=ttyS0 panic=-1"],
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    os.set_blocking(proc.stdout.fileno(), False)
    out = b""
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline and b"Linux version" not in out and proc.poll() is None:
        time.sleep(0.1)
        out += proc.stdout.read() or b""
    proc.kill()
    proc.wait()
    if b"Linux version" in out:
        return True, "a probe boot printed the kernel's first line"
    return False, "/dev/kvm opens, but a probe boot printed nothing in 5 s"


def vm():
    if "vm" not in state or "booted" not in state:
        raise TestFailure("not run: the VM did not boot")
    return state["vm"]


# ---- helpers run in the VM ----

# The PLC: pymodbus in the VM, one connection per call.
GUEST_PRELUDE = r"""
import json, socket, ssl, struct, subprocess, time
from pymodbus.client import ModbusTcpClient

def plc(port):
    c = ModbusTcpClient("127.0.0.1", port=port, timeout=10, retries=0)
    assert c.connect(), "Modbus connect to port %d" % port
    return c

def ir(port, address, count=1):
    c = plc(port)
    try:
        rr = c.read_input_registers(address, count, slave=1)
        assert not rr.isError(), "read input registers %d: %s" % (address, rr)
        return rr.registers
    finally:
        c.close()

def pulse(port, coil, hold=0.0):
    # 0 then 1 on a trigger coil; the connection kept 'hold' s after.
    c = plc(port)
    try:
        out = []
        for v in (False, True):
            rr = c.write_coil(coil, v, slave=1)
            out.append(getattr(rr, "exception_code", 0) if rr.isError() else 0)
        time.sleep(hold)
        return out
    finally:
        c.close()

def mono():
    return time.clock_gettime(time.CLOCK_MONOTONIC)
"""


def show(unit, *props):
    out = vm().sh("systemctl show %s -p %s" % (unit, ",".join(props)))
    return dict(line.split("=", 1) for line in out.splitlines() if "=" in line)


def journal(args, after=None):
    """journalctl -o json entries; 'after': only those after that mark()."""
    since = " --since=@%d" % (after // 1000000) if after else ""
    out = vm().sh("journalctl --no-pager -o json %s%s" % (args, since), timeout=60)
    entries = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    return [e for e in entries if not after or int(e["__REALTIME_TIMESTAMP"]) > after]


def mark():
    """Now, as the journal stamps entries (microseconds of wall time). Not a
    cursor: journalctl --after-cursor with a unit match skips the first
    matching entry when the cursor's own entry does not match (systemd 252)."""
    return vm().py("result = int(time.time() * 1000000)")


def robot_log(unit="robot", after=None):
    return [e["MESSAGE"] for e in journal("-u %s" % unit, after)
            if isinstance(e.get("MESSAGE"), str)]


def sim_commands(unit="robot", after=None, name=None):
    """What jakasim (running as 'unit') received, as parsed requests."""
    decoder = json.JSONDecoder()
    out = []
    for line in robot_log(unit, after):
        at = line.find(SIM_COMMAND_MARK)
        if at < 0 or not line[at + len(SIM_COMMAND_MARK):].startswith("{"):
            continue
        request, _ = decoder.raw_decode(line[at + len(SIM_COMMAND_MARK):])
        if name is None or request.get("cmdName") == name:
            out.append(request)
    return out


def delivered(unit="robot", after=None):
    """The commands a PLC caused: all but the gateway's own housekeeping."""
    return [c for c in sim_commands(unit, after) if not (
        c.get("cmdName") == "set_network_exception_handle" or
        (c.get("cmdName") or "").startswith("get_"))]


def wait_vm(cond, timeout, what, interval=0.2):
    """wait_until, polling the VM (each look is a round trip to its agent)
    every 0.2 s."""
    return wait_until(cond, timeout, what, interval)


def active(unit):
    return show(unit, "ActiveState")["ActiveState"] == "active"


def conf_with(base, changes):
    """The configuration text 'base' with changes {section: {key: value}}:
    each key's line replaced, missing keys added at the end of the section."""
    out, section, pending = [], None, {s: dict(kv) for s, kv in changes.items()}

    def flush():
        for k, v in pending.pop(section, {}).items():
            out.append("%s = %s" % (k, v))

    for line in base.splitlines():
        m = re.match(r"^\[(\w+)\]", line)
        if m:
            flush()
            section = m.group(1)
        else:
            m = re.match(r"^(\w+)\s*=", line)
            if m and m.group(1) in pending.get(section, {}):
                line = "%s = %s" % (m.group(1), pending[section].pop(m.group(1)))
        out.append(line)
    flush()
    for s, kv in pending.items():
        out.append("[%s]" % s)
        out += ["%s = %s" % (k, v) for k, v in kv.items()]
    return "\n".join(out) + "\n"


def set_conf(changes, path="/etc/jakagw/jakagw.conf"):
    vm().write(path, conf_with(state["conf"], changes))


def restart(unit="jakagw.service", daemon_reload=False):
    if daemon_reload:
        vm().sh("systemctl daemon-reload")
    code, out = vm().rc("systemctl restart %s" % unit, timeout=60)
    check(code == 0, "systemctl restart %s: %s\n%s\n%s" % (
        unit, out, unit_story(unit), vm().sh("ls -l /etc/systemd/system/*.wants", ok=None)))
    check(active(unit), "%s is not active after a restart: %s" % (
        unit, vm().sh("systemctl status --no-pager -l %s" % unit, ok=None)))


def restore(daemon_reload=False):
    """The packaged configuration back, and jakagw.service running on it
    (daemon_reload: after a change of [rtu] or of a drop-in)."""
    set_conf({})
    restart(daemon_reload=daemon_reload)


def wait_robot_link(port=502):
    """The gateway holds the robot's handler (it is connected)."""
    wait_vm(lambda: vm().py("result = ir(%d, %d)[0]" % (port, IR_HANDLE)) == 2, 30,
            "the robot to accept the gateway's handler (port %d)" % port)


def security(unit="jakagw.service"):
    out = vm().sh("systemd-analyze security --no-pager %s" % unit)
    m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", out)
    check(m, "no exposure rating: %s" % out[-500:])
    return float(m.group(1))


# ---- the seccomp detector ----

def seccomp_kills(exclude=()):
    """SIGSYS kills and 'audit: type=1326' (seccomp) lines of this boot:
    the kernel's and systemd's own words for a filtered system call."""
    found = []
    kmsg = vm().sh("journalctl --no-pager -k -o cat; dmesg", ok=None)
    for line in kmsg.splitlines():
        if "type=1326" in line and not any(e in line for e in exclude):
            found.append(line.strip())
    for e in journal("_PID=1"):
        msg = e.get("MESSAGE", "")
        if isinstance(msg, str) and ("status=31/SYS" in msg or "signal=SYS" in msg) and \
                not any(x in (e.get("UNIT", "") + msg) for x in exclude):
            found.append("%s: %s" % (e.get("UNIT"), msg))
    return found


# ---- cases ----

def case_boot():
    """The image (cached when its inputs are unchanged) boots to the agent."""
    start = time.monotonic()
    deb = os.environ.get("JAKAGW_SERVICE_DEB")
    if not deb:
        options = (os.environ.get("DEB_BUILD_OPTIONS", "") + " nocheck").strip()
        r = subprocess.run(["make", "-s", "-C", ROOT, "BUILD=" + os.path.relpath(BUILD, ROOT),
                            "deb"], capture_output=True, text=True, timeout=900,
                           env=dict(os.environ, DEB_BUILD_OPTIONS=options))
        check(r.returncode == 0, "make deb: %s%s" % (r.stdout[-2000:], r.stderr[-2000:]))
        deb = r.stdout.strip().splitlines()[-1]
    check(os.path.isfile(deb), "no package %s" % deb)
    state["deb"] = deb
    deb_s = time.monotonic() - start
    start = time.monotonic()
    r = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "scripts", "make-service-image.py"),
                        VMDIR, deb], capture_output=True, text=True, timeout=1500)
    check(r.returncode == 0, "make-service-image: %s" % r.stderr[-3000:])
    image = r.stdout.strip().splitlines()[-1]
    cached = "cached" in r.stderr
    image_s = time.monotonic() - start
    import glob
    kernels = sorted(glob.glob("/boot/vmlinuz-*"), reverse=True)
    version = next(k[len("/boot/vmlinuz-"):] for k in kernels
                   if os.path.isfile("/boot/initrd.img-" + k[len("/boot/vmlinuz-"):]))
    v = Vm(image, "/boot/vmlinuz-" + version, "/boot/initrd.img-" + version)
    state["booted"] = True
    state["preludes"] = [GUEST_PRELUDE, IDLE_PROBE, TLS_MASTER]
    for code in state["preludes"]:
        v.py(code)
    # The file as the package installs it, and the same with the robot
    # named and writes from any client (the PLCs of the cases are local, the
    # RTU master has no address), which every case from fresh_install on
    # runs with; writes_until_allowed runs the packaged write_allow.
    state["packaged"] = v.sh("cat /etc/jakagw/jakagw.conf")
    state["conf"] = conf_with(state["packaged"], {"robot": {"host": "127.0.0.1"},
                                                  "modbus": {"write_allow": ""}})
    global COIL_POWER_ON, IR_INTERP, IR_HANDLE
    import csv
    import io
    for row in csv.DictReader(io.StringIO(v.sh("jakagw --print-map csv"))):
        ADDR.setdefault((row["table"], row["name"]), int(row["address"]))
    COIL_POWER_ON = ADDR[("coil", "cmd_power_on")]
    IR_INTERP = ADDR[("input_register", "interp_state")]
    IR_HANDLE = ADDR[("input_register", "robot_handle")]
    target = show("multi-user.target", "ActiveEnterTimestampMonotonic")
    mu_s = int(target["ActiveEnterTimestampMonotonic"]) / 1e6
    analyze = v.sh("systemd-analyze time", ok=None).strip().splitlines()
    figure("package: %s (%.0f s); image %s (%.0f s); kernel %s, %s (%s)"
           % (os.path.basename(deb), deb_s, "cached" if cached else "built", image_s, version,
              "KVM" if v.kvm else "TCG", v.kvm_why))
    figure("boot: agent answered %.1f s after qemu started; multi-user.target at %.1f s "
           "of guest uptime (%s)" % (v.boot_s, mu_s, analyze[0] if analyze else "?"))
    # The detector finds a filtered system call when there is one: a
    # throw-away unit whose filter forbids uname(2) runs uname.
    v.sh("systemd-run --wait -q --unit=seccomp-probe -p SystemCallFilter=~uname /usr/bin/uname",
         ok=None)
    found = wait_vm(lambda: seccomp_kills(), 10, "the probe's SIGSYS to be seen")
    check(any("seccomp-probe" in f or 'comm="uname"' in f for f in found),
          "the detector saw no kill of the probe: %s" % found)
    state["seccomp_exclude"] = ('comm="uname"', "seccomp-probe")


def listening_ports():
    """The TCP ports something listens on in the VM."""
    return sorted({int(line.split()[3].rsplit(":", 1)[1])
                   for line in vm().sh("ss -ltnH").splitlines() if line.strip()})


def case_fresh_install():
    """The package as apt installed it: jakagw.service enabled, and at boot
    skipped (ExecCondition=), since the packaged file names no robot:
    nothing listens on 502 or 802, no jakagw process, the robot saw no
    connection; the journal says why. With [robot] host named and a
    restart (the guide's steps), it runs."""
    v = vm()
    check(v.sh("systemctl is-enabled jakagw.service", ok=None).strip() == "enabled",
          "jakagw.service is not enabled by the package")
    p = show("jakagw.service", "ActiveState", "ExecMainPID")
    check(p["ActiveState"] != "active", "jakagw.service runs with the packaged file: %s" % p)
    check(v.rc("pgrep -x jakagw")[0] == 1, "a jakagw process runs: %s" % v.sh("ps -ef"))
    ports = listening_ports()
    check(502 not in ports and 802 not in ports, "listening before configured: %s" % ports)
    check(not sim_commands(), "the robot received before configured: %s" % sim_commands())
    why = [e["MESSAGE"] for e in journal("-b -u jakagw.service")
           if "names no robot" in str(e.get("MESSAGE", ""))]
    check(why, "no journal line says why jakagw.service did not start")
    state["configured_at"] = mark()
    v.write("/etc/jakagw/jakagw.conf", state["conf"])
    restart()
    wait_robot_link()
    figure("fresh_install: enabled, not started at boot (%r); listening %s; robot received "
           "nothing; with [robot] host named and a restart: active" % (why[0], ports))


def case_ready():
    """Once configured (fresh_install), active; READY (Type=notify) came
    once the Modbus listener was bound; a status line with links and
    clients."""
    v = vm()
    check("configured_at" in state, "not run: fresh_install did not configure the service")
    p = show("jakagw.service", "ActiveState", "SubState", "Type", "NRestarts", "StatusText",
             "MainPID", "ActiveEnterTimestampMonotonic", "ExecMainStartTimestampMonotonic")
    check(p["ActiveState"] == "active" and p["SubState"] == "running" and p["Type"] == "notify",
          "jakagw.service after boot: %s" % p)
    check(p["NRestarts"] == "0", "restarted during boot: %s" % p)
    # The listener's log line comes before systemd's "Started" (READY).
    entries = journal("-u jakagw.service", state["configured_at"])
    listen = [e for e in entries if e.get("_PID") == p["MainPID"] and
              "listening on" in str(e.get("MESSAGE", "")) and "502" in str(e.get("MESSAGE"))]
    started = [e for e in entries if e.get("_PID") == "1" and e.get("JOB_TYPE") == "start"
               and e.get("JOB_RESULT") == "done"]
    check(listen and started, "no listening line (%d) or start job (%d) in the journal"
          % (len(listen), len(started)))
    check(int(listen[0]["__MONOTONIC_TIMESTAMP"]) <= int(started[0]["__MONOTONIC_TIMESTAMP"]),
          "READY came before the listener was bound")
    check(len(started) == 1, "jakagw.service started %d times" % len(started))
    wait_robot_link()
    check(v.py("result = ir(502, 0)[0]") == MAGIC, "the map magic on port 502")
    status = wait_vm(lambda: (lambda s: s if "Modbus clients" in s and "up" in s else None)(
        v.sh("systemctl status --no-pager jakagw.service", ok=None)), 10, "the status line")
    line = next(l.strip() for l in status.splitlines() if l.strip().startswith("Status:"))
    check("status link" in line and "command link" in line, "status line: %s" % line)
    ss = v.sh("ss -ltnpH 'sport = :502'")
    check("jakagw" in ss, "port 502 is not jakagw's: %s" % ss)
    figure("ready: active %.2f s after its start (exec to READY), boot to READY %.1f s; %s"
           % ((int(p["ActiveEnterTimestampMonotonic"]) -
               int(p["ExecMainStartTimestampMonotonic"])) / 1e6,
              int(p["ActiveEnterTimestampMonotonic"]) / 1e6, line))


def reload_and_wait(expect):
    """systemctl reload, then the gateway's line for it: seconds taken."""
    v = vm()
    c = mark()
    t0 = v.py("result = mono()")
    v.sh("systemctl reload jakagw.service")
    lines = wait_vm(lambda: [e for e in journal("-u jakagw.service", c)
                             if expect in str(e.get("MESSAGE", ""))], 15,
                    "the reload's line %r" % expect)
    return int(lines[0]["__MONOTONIC_TIMESTAMP"]) / 1e6 - t0


IDLE_PROBE = r"""
def idle_closed(port, within):
    s = socket.create_connection(("127.0.0.1", port))
    s.settimeout(within)
    t = time.monotonic()
    try:
        data = s.recv(1)
    except socket.timeout:
        return None
    except ConnectionResetError:
        data = b""
    finally:
        s.close()
    return time.monotonic() - t if data == b"" else None
"""


def case_reload():
    """systemctl reload applies a changed key (idle_timeout_ms: an idle PLC
    connection is closed after 0.5 s instead of 60 s); a bad file is
    refused and the running configuration kept, in the same process."""
    v = vm()
    pid = show("jakagw.service", "MainPID")["MainPID"]
    check(v.py("result = idle_closed(502, 2)") is None, "closed before the reload")
    set_conf({"modbus": {"idle_timeout_ms": "500"}})
    took = reload_and_wait("changes applied")
    closed = v.py("result = idle_closed(502, 3)")
    check(closed is not None and 0.4 <= closed <= 2.5,
          "idle connection closed after %s s with idle_timeout_ms 500" % closed)
    v.write("/etc/jakagw/jakagw.conf", state["conf"].replace("[modbus]\n",
                                                             "[modbus]\nidle_timeout_ms = soon\n"))
    reload_and_wait("reload refused")
    p = show("jakagw.service", "MainPID", "ActiveState")
    check(p["MainPID"] == pid and p["ActiveState"] == "active", "after a bad file: %s" % p)
    again = v.py("result = idle_closed(502, 3)")
    check(again is not None and again <= 2.5, "the bad file changed the running "
          "configuration: idle connection closed after %s" % again)
    # A key that needs a restart ([robot] host, the guide's first edit):
    # the summary line and the status line name it until it is undone.
    set_conf({"robot": {"host": "localhost"}})
    c = mark()
    reload_and_wait("need a restart")
    summary = [e["MESSAGE"] for e in journal("-u jakagw.service", c)
               if "need a restart" in str(e.get("MESSAGE", ""))][0]
    check("[robot] host" in summary and "systemctl restart" in summary,
          "the summary does not name the key: %s" % summary)
    status = show("jakagw.service", "StatusText")["StatusText"]
    check("restart needed for [robot] host" in status, "status line: %s" % status)
    check(show("jakagw.service", "MainPID")["MainPID"] == pid, "the reload restarted it")
    set_conf({})
    reload_and_wait("changes applied")
    status_after = show("jakagw.service", "StatusText")["StatusText"]
    check("restart needed" not in status_after, "status line once undone: %s" % status_after)
    figure("reload: %.3f s from systemctl reload to the gateway's summary line; idle "
           "connection closed %.2f s after the reload set 500 ms, %.2f s after a refused one; "
           "a new [robot] host: %r, status %r"
           % (took, closed, again, summary, status))


def case_watchdog():
    """SIGSTOP of the main process: systemd's watchdog restarts it within
    WatchdogSec + RestartSec; meanwhile the robot's own handler paused the
    running program; nothing is delivered twice or replayed."""
    v = vm()
    # A robot running its program (jakasim --auto-run, started again), and
    # the gateway connected to it.
    v.sh("systemctl restart robot.service")
    wait_robot_link()
    wait_vm(lambda: v.py("result = ir(502, %d)[0]" % IR_INTERP) == RUNNING, 20,
            "the program running")
    c = mark()
    check(v.py("result = pulse(502, %d)" % COIL_POWER_ON) == [0, 0], "power_on pulse refused")
    wait_vm(lambda: len(sim_commands(after=c, name="power_on")) == 1, 10, "power_on at the robot")
    sent = delivered(after=c)
    p = show("jakagw.service", "MainPID", "NRestarts")
    handlers = len(sim_commands(name="set_network_exception_handle"))
    t0 = v.py("import os, signal\nos.kill(%s, signal.SIGSTOP)\nresult = mono()" % p["MainPID"])
    wait_vm(lambda: (lambda q: q["NRestarts"] == str(int(p["NRestarts"]) + 1) and
                     q["ActiveState"] == "active" and q["MainPID"] != p["MainPID"])(
        show("jakagw.service", "NRestarts", "ActiveState", "MainPID")),
        WATCHDOG_S + RESTART_S + 20, "systemd to restart the stopped gateway")
    entries = journal("-u jakagw.service", c)
    dog = [e for e in entries if e.get("_PID") == "1" and
           "atchdog timeout" in str(e.get("MESSAGE", ""))]
    started = [e for e in entries if e.get("_PID") == "1" and e.get("JOB_TYPE") == "start"
               and e.get("JOB_RESULT") == "done"]
    check(dog, "no watchdog timeout in the journal")
    check(len(started) == 1, "%d starts after the SIGSTOP" % len(started))
    fired = int(dog[0]["__MONOTONIC_TIMESTAMP"]) / 1e6 - t0
    # The new process: its exec (the restart) and its READY (the start job done).
    execd = int(show("jakagw.service", "ExecMainStartTimestampMonotonic")[
        "ExecMainStartTimestampMonotonic"]) / 1e6 - t0
    back = int(started[0]["__MONOTONIC_TIMESTAMP"]) / 1e6 - t0
    check(fired <= WATCHDOG_S + 2, "the watchdog fired %.1f s after SIGSTOP" % fired)
    # Each start first runs the units' start condition (ExecCondition=:
    # jakagw --check-start with the unit's command line), timed here once.
    cond_s = v.py("t = mono()\nsubprocess.run(['/usr/libexec/jakagw/jakagw-condition', "
                  "'jakagw.service', '/usr/sbin/jakagw', '-c', '/etc/jakagw/jakagw.conf'], "
                  "capture_output=True)\nresult = mono() - t")
    check(execd <= WATCHDOG_S + RESTART_S + 2 + cond_s,
          "restarted %.1f s after SIGSTOP: WatchdogSec %d + RestartSec %d + the start "
          "condition %.1f s" % (execd, WATCHDOG_S, RESTART_S, cond_s))
    # Where the restart's time goes, from systemd's own lines: the old
    # process gone, the restart scheduled (RestartSec= later), the start
    # job begun (the condition runs from there to the new process's exec).
    def at(text):
        hits = [e for e in entries if e.get("_PID") == "1" and text in str(e.get("MESSAGE", ""))]
        return int(hits[0]["__MONOTONIC_TIMESTAMP"]) / 1e6 - t0 if hits else float("nan")
    gone, scheduled, starting = (at("Main process exited"), at("Scheduled restart job"),
                                 at("Starting "))
    # The check alone, without asking systemd for the command line.
    check_s = v.py("t = mono()\nsubprocess.run(['/usr/sbin/jakagw', '-c', '/etc/jakagw/jakagw.conf', "
                   "'--check-start'], capture_output=True)\nresult = mono() - t")
    # The robot paused the program by itself, once.
    acts = [l for l in robot_log(after=c) if "network exception on command connection" in l]
    check(len(acts) == 1 and "paused the program" in acts[0], "the robot's handler: %s" % acts)
    wait_vm(lambda: len(sim_commands(name="set_network_exception_handle")) > handlers, 30,
            "the new gateway to set the handler again")
    wait_robot_link()
    check(v.py("result = ir(502, %d)[0]" % IR_INTERP) == PAUSED,
          "the program is not paused after the restart")
    time.sleep(2)  # what a replay would send arrives within this
    after = delivered(after=c)
    check(after == sent, "delivered before the SIGSTOP %s, by the end %s" % (sent, after))
    figure("watchdog: SIGSTOP -> watchdog timeout %.1f s -> old process gone %.1f s -> restart "
           "scheduled %.1f s -> start job %.1f s -> new process %.1f s (limit %d + %d, the start "
           "condition %.2f s, its check alone %.2f s) -> READY %.1f s; robot paused the program; "
           "commands delivered: %d (%s), none again"
           % (fired, gone, scheduled, starting, execd, WATCHDOG_S, RESTART_S, cond_s, check_s,
              back, len(after), ", ".join(x["cmdName"] for x in after)))


def caps_of(pid):
    text = vm().sh("cat /proc/%s/status" % pid)
    return {k: int(v, 16) for k, v in re.findall(r"^(Cap\w+):\s+([0-9a-f]+)$", text, re.M)}


def case_socket():
    """jakagw.socket on port 502, started while jakagw.service runs (it
    stops it: Conflicts=): the first PLC connection starts the service,
    which has no capability at all; starting jakagw.service again stops the
    socket and its service."""
    v = vm()
    v.sh("systemctl start jakagw.socket")
    check(not active("jakagw.service") and not active("jakagw-socket.service"),
          "a service runs before the first connection")
    ss = v.sh("ss -ltnpH 'sport = :502'")
    check("systemd" in ss and "jakagw" not in ss, "port 502 is not held by systemd: %s" % ss)
    t0 = time.monotonic()
    check(v.py("result = ir(502, 0)[0]") == MAGIC, "the first connection was not served")
    first = time.monotonic() - t0
    check(active("jakagw-socket.service"), "jakagw-socket.service is not active")
    p = show("jakagw-socket.service", "MainPID", "StatusText")
    caps = caps_of(p["MainPID"])
    check(caps and all(value == 0 for value in caps.values()), "capabilities: %s" % caps)
    user = v.sh("ps -o user= -p %s" % p["MainPID"]).strip()
    check(user not in ("root", "0"), "runs as %s" % user)
    v.sh("systemctl start jakagw.service")
    check(active("jakagw.service") and not active("jakagw.socket") and
          not active("jakagw-socket.service"), "back to jakagw.service: %s" %
          v.sh("systemctl list-units --all --no-legend 'jakagw*'"))
    figure("socket: first connection answered %.2f s after connect (service started by it); "
           "%s; user %s; status %r" % (first, " ".join("%s=%x" % kv for kv in
                                                       sorted(caps.items())), user,
                                       p["StatusText"]))


def case_instances():
    """jakagw@a and jakagw@b for two robots (two jakasims), each with its
    own file and ports; a command on one reaches its robot only."""
    v = vm()
    for name, base in (("a", 11000), ("b", 12000)):
        v.sh("systemd-run -q --unit=robot-%s /usr/bin/jakasim --log-commands --auto-run "
             "--status-port %d --command-port %d" % (name, base, base + 1))
        v.write("/etc/jakagw/%s.conf" % name, conf_with(state["conf"], {
            "robot": {"status_port": str(base), "command_port": str(base + 1)},
            "modbus": {"port": "1502" if name == "a" else "2502"}}))
    v.sh("systemctl start jakagw@a.service jakagw@b.service")
    pa = show("jakagw@a.service", "MainPID", "ActiveState", "ExecStart")
    pb = show("jakagw@b.service", "MainPID", "ActiveState", "ExecStart")
    check(pa["ActiveState"] == pb["ActiveState"] == "active", "instances: %s %s" % (pa, pb))
    check(pa["MainPID"] != pb["MainPID"], "one process for two instances")
    check("/etc/jakagw/a.conf" in pa["ExecStart"] and "/etc/jakagw/b.conf" in pb["ExecStart"],
          "files: %s / %s" % (pa["ExecStart"], pb["ExecStart"]))
    counts = {}
    for name, port in (("a", 1502), ("b", 2502)):
        wait_robot_link(port)
        check(v.py("result = ir(%d, 0)[0]" % port) == MAGIC, "magic on port %d" % port)
    check(v.py("result = pulse(1502, %d)" % COIL_POWER_ON) == [0, 0], "pulse on a")
    wait_vm(lambda: len(sim_commands("robot-a", name="power_on")) == 1, 10, "power_on at robot a")
    time.sleep(1)
    check(not sim_commands("robot-b", name="power_on"), "robot b got a's power_on")
    check(v.py("result = pulse(2502, %d)" % COIL_POWER_ON) == [0, 0], "pulse on b")
    wait_vm(lambda: len(sim_commands("robot-b", name="power_on")) == 1, 10, "power_on at robot b")
    time.sleep(1)
    for name in ("a", "b"):
        counts[name] = delivered("robot-" + name)
        check(len(sim_commands("robot-" + name, name="power_on")) == 1, "robot %s" % name)
    v.sh("systemctl stop jakagw@a.service jakagw@b.service robot-a.service robot-b.service")
    v.sh("rm -f /etc/jakagw/a.conf /etc/jakagw/b.conf")
    figure("instances: jakagw@a (pid %s, port 1502) and jakagw@b (pid %s, port 2502); "
           "commands delivered: a %d, b %d" % (pa["MainPID"], pb["MainPID"],
                                               len(counts["a"]), len(counts["b"])))


TLS_SETUP = r"""
set -e
mkdir -p /root/ca/certs /etc/jakagw/tls
cd /root/ca
touch index.txt
echo 1000 > serial
cat > ca.cnf <<'EOF'
[ca]
default_ca = plc_ca
[plc_ca]
dir = .
database = index.txt
serial = serial
new_certs_dir = certs
certificate = ca.crt
private_key = ca.key
default_md = sha256
default_days = 825
policy = any_name
unique_subject = no
[any_name]
commonName = supplied
EOF
openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc -days 3650 \
    -subj "/CN=Cell PLC CA" -keyout ca.key -out ca.crt 2>/dev/null
printf 'subjectAltName = IP:127.0.0.1, DNS:localhost\nextendedKeyUsage = serverAuth\n' > gateway.ext
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc \
    -subj "/CN=jakagw" -keyout gateway.key -out gateway.csr 2>/dev/null
openssl ca -config ca.cnf -batch -notext -extfile gateway.ext -in gateway.csr -out gateway.crt 2>/dev/null
printf 'extendedKeyUsage = clientAuth\n1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:operator\n' > operator.ext
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc \
    -subj "/CN=plc-operator" -keyout operator.key -out operator.csr 2>/dev/null
openssl ca -config ca.cnf -batch -notext -extfile operator.ext -in operator.csr -out operator.crt 2>/dev/null
install -m 0644 ca.crt gateway.crt /etc/jakagw/tls/
install -m 0600 gateway.key /etc/jakagw/tls/
"""

# [tls] on, its key the credential mbaps.key; role operator may power on.
TLS_CHANGES = {"tls": {"enabled": "true", "certificate": "/etc/jakagw/tls/gateway.crt",
                       "private_key": "mbaps.key", "client_ca": "/etc/jakagw/tls/ca.crt"},
               "roles": {"operator": "power"}}
CREDENTIAL = "[Service]\nLoadCredential=mbaps.key:/etc/jakagw/tls/gateway.key\n"

TLS_MASTER = r"""
def tls_requests(port, pdus):
    # Modbus/TCP Security: MBAP frames inside TLS, with the operator's
    # client certificate; the replies' PDUs, and the TLS version.
    ctx = ssl.create_default_context(cafile="/root/ca/ca.crt")
    ctx.load_cert_chain("/root/ca/operator.crt", "/root/ca/operator.key")
    replies = []
    with socket.create_connection(("127.0.0.1", port), timeout=10) as raw:
        with ctx.wrap_socket(raw, server_hostname="127.0.0.1") as s:
            for tid, pdu in enumerate(pdus, 1):
                s.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, 1) + pdu)
                data = b""
                while len(data) < 7 or len(data) < 6 + struct.unpack(">H", data[4:6])[0]:
                    chunk = s.recv(260)
                    assert chunk, "TLS connection closed"
                    data += chunk
                replies.append(data[7:])
            return replies, s.version()

def tls_ir(port, address):
    replies, version = tls_requests(port, [struct.pack(">BHH", 4, address, 1)])
    return struct.unpack(">H", replies[0][2:4])[0], version

def tls_pulse(port, coil):
    replies, _ = tls_requests(port, [struct.pack(">BHH", 5, coil, v) for v in (0, 0xFF00)])
    return [r[1] if r[0] & 0x80 else 0 for r in replies]
"""


def case_credential():
    """The TLS private key (root-only, 0600) through LoadCredential= (the
    drop-in the README shows); a TLS master is served on port 802."""
    v = vm()
    v.sh(TLS_SETUP)
    v.sh("mkdir -p /etc/systemd/system/jakagw.service.d")
    v.write("/etc/systemd/system/jakagw.service.d/credential.conf", CREDENTIAL)
    set_conf(TLS_CHANGES)
    restart(daemon_reload=True)
    mode = v.sh("stat -c '%a %U' /etc/jakagw/tls/gateway.key").strip()
    check(mode == "600 root", "the key's mode changed: %s" % mode)
    magic, version = wait_vm(lambda: v.py("result = tls_ir(802, 0)"), 10, "a TLS answer")
    check(magic == MAGIC, "magic over TLS: %#x" % magic)
    logs = v.sh("journalctl --no-pager -o cat -u jakagw.service -n 200")
    check("mbaps: listening" in logs, "no mbaps listener line")
    state["tls"] = True  # left configured for the journal case
    figure("credential: key 0600 root, read through LoadCredential=; TLS master (%s, client "
           "certificate with role operator) read the magic on port 802" % version)


def refused(port):
    """Whether a connection to 'port' in the VM is refused."""
    return vm().py("try:\n    socket.create_connection(('127.0.0.1', %d), timeout=5).close()\n"
                   "    result = False\nexcept ConnectionRefusedError:\n    result = True"
                   % port)


def case_tls_only():
    """Socket mode for Modbus/TCP Security alone ([modbus] enabled = false,
    [tls] on, its key a credential): the documented command (systemctl
    enable --now jakagw-socket.service) holds port 802 alone, where a TLS
    master is served; 502 refuses connections. The documented command back
    leaves jakagw.service alone running."""
    v = vm()
    check(state.get("tls"), "not run: the credential case did not set up TLS")
    v.sh("mkdir -p /etc/systemd/system/jakagw-socket.service.d")
    v.write("/etc/systemd/system/jakagw-socket.service.d/credential.conf", CREDENTIAL)
    set_conf(dict(TLS_CHANGES, modbus={"enabled": "false"}))
    try:
        code, out = v.rc("systemctl enable --now jakagw-socket.service", timeout=120)
        check(code == 0, "enable --now jakagw-socket.service: %s\n%s" % (
            out, unit_story("jakagw-socket.service")))
        wait_vm(lambda: active("jakagw-socket.service"), 20, "jakagw-socket.service active")
        ports = listening_ports()
        ss = v.sh("ss -ltnpH 'sport = :802'")
        check(ports.count(802) == 1 and 502 not in ports, "listening: %s" % ports)
        check("systemd" in ss, "port 802 is not systemd's socket: %s" % ss)
        magic, version = wait_vm(lambda: v.py("result = tls_ir(802, 0)"), 10, "a TLS answer")
        check(magic == MAGIC, "magic over TLS: %#x" % magic)
        check(refused(502), "port 502 accepts connections in a TLS-only set-up")
        check(not active("jakagw.service"), "jakagw.service runs beside the socket service")
    finally:
        set_conf(TLS_CHANGES)
        v.sh("systemctl disable jakagw-socket.service && systemctl restart jakagw.service",
             timeout=120)
    check(active("jakagw.service") and not active("jakagw-socket.service") and
          not active("jakagw.socket") and not active("jakagw-mbaps.socket"),
          "back to jakagw.service: %s" % v.sh("systemctl list-units --all --no-legend 'jakagw*'"))
    figure("tls_only: listening on %s (802 systemd's), TLS master (%s) read the magic; 502 "
           "refused; back to jakagw.service with one command" % (ports, version))


def case_credential_rtu():
    """The TLS key as a credential (LoadCredential=, as documented) and
    [rtu] on /dev/ttyS1: jakagw-generator reads the file with the
    credential, as the service does, and gives the unit the port; a master
    on this machine's end of the line reads the magic and triggers power_on
    once."""
    v = vm()
    check(state.get("tls"), "not run: the credential case did not set up TLS")
    set_conf(dict(TLS_CHANGES, rtu={"enabled": "true", "device": "/dev/ttyS1",
                                    "rights": "power"}))
    c = mark()
    restart(daemon_reload=True)
    dropin = v.rc("cat /run/systemd/generator/jakagw.service.d/50-jakagw-rtu.conf")
    check(dropin[0] == 0 and "DeviceAllow=/dev/ttyS1 rw" in dropin[1],
          "no drop-in for /dev/ttyS1: %s; generator: %s" % (dropin[1], [
              e.get("MESSAGE") for e in journal("-t jakagw-generator", c)]))
    wait_vm(lambda: "rtu: " in v.sh("journalctl --no-pager -o cat -u jakagw.service -n 50"),
            10, "the RTU line's log")
    logs = v.sh("journalctl --no-pager -o cat -u jakagw.service -n 50")
    check("No such file" not in logs and "Permission denied" not in logs,
          "the service cannot open /dev/ttyS1:\n%s" % logs[-2000:])
    wait_robot_link()
    rtu_master(v.ptys["rtu"], mark())
    # The test's own files go (a purge keeps files the package never had).
    v.sh("rm -rf /etc/systemd/system/jakagw.service.d /etc/systemd/system/jakagw-socket.service.d"
         " /etc/jakagw/tls")
    state["tls"] = False
    restore(daemon_reload=True)
    figure("credential_rtu: key as credential mbaps.key, [rtu] /dev/ttyS1: the generator's "
           "drop-in, the master read the magic and power_on reached the robot once")


def mbpoll(dev, args, values=()):
    r = subprocess.run(["mbpoll", "-m", "rtu", "-a", "1", "-b", "19200", "-P", "even", "-0",
                        "-1", "-o", "3"] + list(args) + [dev] + list(values),
                       capture_output=True, text=True, timeout=30)
    return r.returncode, r.stdout + r.stderr


def rtu_master(dev, before):
    """mbpoll on this machine's end of the line: the magic, then power_on
    once (0 then 1 on the trigger coil)."""
    code, out = mbpoll(dev, ["-t", "3", "-r", "0", "-c", "1"])
    m = re.search(r"\[\d+\]:\s+(-?\d+)", out)
    check(code == 0 and m and int(m.group(1)) & 0xFFFF == MAGIC,
          "mbpoll read on %s: exit %d\n%s" % (dev, code, out))
    for value in ("0", "1"):
        code, out = mbpoll(dev, ["-t", "0", "-r", str(COIL_POWER_ON)], [value])
        check(code == 0, "mbpoll coil write %s on %s: %s" % (value, dev, out))
    wait_vm(lambda: len(sim_commands(after=before, name="power_on")) == 1, 10,
            "power_on at the robot")
    time.sleep(1)
    check(len(sim_commands(after=before, name="power_on")) == 1, "power_on more than once")


def case_rtu():
    """[rtu] enabled = true and device = /dev/ttyS1 (a serial port whose
    other end is a pty on this machine), then a USB serial adapter by its
    /dev/serial/by-id name: the packaged service opens each with only the
    configuration changed, and a master here reads the map and triggers
    power_on once. systemd-analyze security stays within 0.3."""
    v = vm()
    before_score = security()
    rates = []
    # qemu attaches the USB adapter once its pty's other end is open: the
    # adapter "plugged in" now, and kept so (mbpoll opens and closes it).
    holder = os.open(v.ptys["usbser"], os.O_RDWR | os.O_NOCTTY)
    try:
        rtu_lines(v, before_score, rates)
    finally:
        os.close(holder)


def rtu_lines(v, before_score, rates):
    wait_vm(lambda: v.rc("ls /dev/serial/by-id/")[0] == 0, 30, "the USB adapter's by-id name")
    byid = v.sh("ls /dev/serial/by-id/").split()
    check(len(byid) == 1, "USB serial adapter names: %s" % byid)
    target = v.sh("readlink -f /dev/serial/by-id/%s" % byid[0]).strip()
    check(target == "/dev/ttyUSB0", "by-id name resolves to %s" % target)
    for device, pty in (("/dev/ttyS1", v.ptys["rtu"]),
                        ("/dev/serial/by-id/" + byid[0], v.ptys["usbser"])):
        set_conf({"rtu": {"enabled": "true", "device": device, "rights": "power"}})
        restart(daemon_reload=True)
        c = mark()
        wait_vm(lambda: "rtu: " in v.sh("journalctl --no-pager -o cat -u jakagw.service -n 50"),
                10, "the RTU line's log")
        logs = v.sh("journalctl --no-pager -o cat -u jakagw.service -n 50")
        check("No such file" not in logs and "Permission denied" not in logs,
              "the service cannot open %s:\n%s" % (device, logs[-2000:]))
        wait_robot_link()
        rtu_master(pty, c)
        rates.append(security())
    # systemd took every line of the generator's drop-ins.
    warned = [e.get("MESSAGE") for e in journal("-b _PID=1")
              if "50-jakagw-rtu.conf" in str(e.get("MESSAGE", ""))]
    check(not warned, "systemd on the generator's drop-in: %s" % warned)
    restore(daemon_reload=True)
    figure("rtu: /dev/ttyS1 and %s (/dev/ttyUSB0) served a master on this machine: magic, "
           "power_on once each; systemd-analyze security jakagw.service: %.1f without "
           "[rtu], %.1f with it" % ("/dev/serial/by-id/" + byid[0], before_score, rates[-1]))
    for r in rates:
        check(abs(r - before_score) <= 0.3 + 1e-9, "exposure %.1f -> %.1f" % (before_score, r))


def case_can():
    """[can] on a vcan interface: candump sees the mirror's frames."""
    v = vm()
    v.sh("modprobe vcan && ip link add vcan0 type vcan && ip link set vcan0 up")
    set_conf({"can": {"enabled": "true", "interface": "vcan0"}})
    restart()
    out = v.sh("timeout 3 candump -L vcan0", ok=(0, 124))
    frames = re.findall(r"^\(\d+\.\d+\) vcan0 ([0-9A-F]+)#", out, re.M)
    check(frames, "no CAN frames from the service:\n%s" % out[-1000:])
    ids = sorted({int(f, 16) for f in frames})
    check(all(0x500 <= i < 0x600 for i in ids), "ids outside base_id 0x500: %s" % ids)
    restore()
    v.sh("ip link del vcan0")
    figure("can: %d frames in 3 s on vcan0, %d ids (%#x-%#x)" % (len(frames), len(ids),
                                                                 ids[0], ids[-1]))


def case_journal():
    """A PLC command's audit fields in the journal: client, role, command,
    result (journalctl -o json), for a power_on written over TLS by the
    credential case's master, whose certificate carries role operator."""
    v = vm()
    check(state.get("tls"), "not run: the credential case did not set up TLS")
    wait_robot_link()
    c = mark()
    check(v.py("result = tls_pulse(802, %d)" % COIL_POWER_ON) == [0, 0], "power_on pulse")

    def audit():
        return [e for e in journal("-u jakagw.service", c)
                if e.get("JAKAGW_COMMAND") == "power_on" and e.get("JAKAGW_RESULT")]
    try:
        e = wait_vm(audit, 20, "the audit entry")[0]
    except TestFailure:
        seen = [{k: v for k, v in x.items() if k.startswith("JAKAGW_") or k == "MESSAGE"}
                for x in journal("-u jakagw.service", c)]
        raise TestFailure("no audit entry for power_on; the journal since: %s; robot: %s; "
                          "last lines: %s" % (seen, sim_commands(after=c), v.sh(
                              "journalctl --no-pager -o cat -u jakagw.service -n 15")))
    for key in ("JAKAGW_CLIENT", "JAKAGW_ROLE", "JAKAGW_COMMAND", "JAKAGW_RESULT"):
        check(e.get(key), "no %s: %s" % (key, e))
    check(e["JAKAGW_CLIENT"].startswith("127.0.0.1"), "client %s" % e["JAKAGW_CLIENT"])
    check(e["JAKAGW_ROLE"] == "operator" and e["JAKAGW_RESULT"] == "done" and
          e.get("JAKAGW_TRANSPORT") == "mbaps", "audit entry: %s" % e)
    check(len(sim_commands(after=c, name="power_on")) == 1, "power_on not delivered once")
    figure("journal: " + ", ".join("%s=%s" % (k, e[k]) for k in sorted(e)
                                   if k.startswith("JAKAGW_")))


def case_upgrade():
    """apt install of a newer build while the service runs: restarted once,
    the edited configuration kept, nothing delivered twice."""
    v = vm()
    edited = conf_with(state["conf"], {"modbus": {"idle_timeout_ms": "30000"}}) + \
        "; edited on site\n"
    v.write("/etc/jakagw/jakagw.conf", edited)
    restart()
    wait_robot_link()
    c = mark()
    check(v.py("result = pulse(502, %d)" % COIL_POWER_ON) == [0, 0], "power_on pulse")
    wait_vm(lambda: len(sim_commands(after=c, name="power_on")) == 1, 10, "power_on")
    sent = delivered(after=c)
    inv = show("jakagw.service", "InvocationID")["InvocationID"]
    handlers = len(sim_commands(name="set_network_exception_handle"))
    newer = v.sh("ls /root/debs/*+upgrade1.deb").strip()
    t0 = time.monotonic()
    apt_at = mark()
    v.sh("DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends %s" % newer,
         timeout=300)
    took = time.monotonic() - t0
    version = v.sh("dpkg-query -W -f='${Version}' jakagw")
    check(version.endswith("+upgrade1"), "installed: %s" % version)
    check(v.sh("cat /etc/jakagw/jakagw.conf") == edited, "the upgrade changed the edited file")
    p = show("jakagw.service", "InvocationID", "ActiveState")
    check(p["ActiveState"] == "active" and p["InvocationID"] != inv, "after the upgrade: %s" % p)
    starts = [e for e in journal("-u jakagw.service", c)
              if e.get("_PID") == "1" and e.get("JOB_TYPE") == "start" and
              e.get("JOB_RESULT") == "done"]
    check(len(starts) == 1, "%d starts during the upgrade" % len(starts))
    stops = [e for e in journal("-u jakagw.service", c) if e.get("_PID") == "1" and
             e.get("JOB_TYPE") in ("stop", "restart") and e.get("JOB_RESULT") is None]
    stopped_at = (int(stops[0]["__REALTIME_TIMESTAMP"]) - apt_at) / 1e6 if stops else -1
    started_at = (int(starts[0]["__REALTIME_TIMESTAMP"]) - apt_at) / 1e6
    wait_vm(lambda: len(sim_commands(name="set_network_exception_handle")) > handlers, 30,
            "the upgraded gateway to reconnect")
    time.sleep(2)
    check(delivered(after=c) == sent, "delivered again: %s" % delivered(after=c))
    figure("upgrade: apt install %s in %.1f s (the service stopping at %.1f s, started again "
           "at %.1f s), one restart, edited file kept; commands delivered %d, none again"
           % (version, took, stopped_at, started_at, len(sent)))


def gateways():
    """The running jakagw processes: {pid: executable}, ' (deleted)' marking
    one that runs a binary the package has replaced or removed."""
    out = vm().sh("for p in $(pgrep -x jakagw); do echo $p $(readlink /proc/$p/exe); done",
                  ok=None)
    return {int(line.split()[0]): line.split(None, 1)[1] for line in out.splitlines()
            if line.strip()}


def start_instance(name="a", port=1502, base=11000):
    """jakagw@NAME for a jakasim of its own (robot-NAME), on Modbus port
    'port': started, its map read."""
    v = vm()
    if not active("robot-%s.service" % name):
        v.sh("systemd-run -q --unit=robot-%s /usr/bin/jakasim --log-commands --auto-run "
             "--status-port %d --command-port %d" % (name, base, base + 1))
    v.write("/etc/jakagw/%s.conf" % name, conf_with(state["conf"], {
        "robot": {"status_port": str(base), "command_port": str(base + 1)},
        "modbus": {"port": str(port)}}))
    v.sh("systemctl start jakagw@%s.service" % name)
    wait_robot_link(port)


def unit_story(unit):
    """What systemd and the generator said, for a failure message."""
    return vm().sh("systemctl status --no-pager -l %s; journalctl --no-pager -b -n 30 -u %s "
                   "-t jakagw-generator" % (unit, unit), ok=None)[-3000:]


def socket_mode():
    """Socket mode by its documented command, served on 502."""
    v = vm()
    code, out = v.rc("systemctl enable --now jakagw-socket.service", timeout=120)
    check(code == 0, "enable --now jakagw-socket.service: %s\n%s" % (
        out, unit_story("jakagw-socket.service")))
    wait_vm(lambda: active("jakagw-socket.service"), 20, "jakagw-socket.service active")
    wait_robot_link()


def case_upgrade_socket():
    """Socket mode (the documented command, jakagw.service left enabled) and
    an instance (jakagw@a, port 1502) running, dpkg -i of a newer build:
    exactly those two services are restarted, once each, on the new binary;
    jakagw.service is not started; 502 and 1502 are served."""
    v = vm()
    socket_mode()
    start_instance()
    units = ("jakagw-socket.service", "jakagw@a.service")
    before = {u: show(u, "MainPID", "InvocationID") for u in units}
    c = mark()
    newer = v.sh("ls /root/debs/*+upgrade2.deb").strip()
    t0 = time.monotonic()
    v.sh("dpkg -i %s" % newer, timeout=300)
    took = time.monotonic() - t0
    check(v.sh("dpkg-query -W -f='${Version}' jakagw").endswith("+upgrade2"), "not upgraded")
    after = {u: show(u, "MainPID", "InvocationID", "ActiveState") for u in units}
    running = gateways()
    state["upgrade2"] = {"before": before, "after": after, "running": running, "mark": c}
    starts = {u: len([e for e in journal("-u %s" % u, c) if e.get("_PID") == "1" and
                      e.get("JOB_TYPE") == "start" and e.get("JOB_RESULT") == "done"])
              for u in units + ("jakagw.service",)}
    state["upgrade2"]["starts"] = starts
    u = "jakagw-socket.service"
    check(after[u]["ActiveState"] == "active" and
          after[u]["InvocationID"] != before[u]["InvocationID"],
          "%s after the upgrade: %s (before %s)" % (u, after[u], before[u]))
    check(starts[u] == 1, "%s started %d times" % (u, starts[u]))
    check(starts["jakagw.service"] == 0 and not active("jakagw.service"),
          "jakagw.service started by the upgrade")
    check("deleted" not in running.get(int(after[u]["MainPID"]), "deleted"),
          "%s runs the old binary: %s" % (u, running))
    wait_robot_link()
    check(v.py("result = ir(502, 0)[0]") == MAGIC, "502 after the upgrade")
    figure("upgrade_socket: dpkg -i in %.1f s; jakagw-socket.service restarted once (pid %s -> "
           "%s, %s); jakagw.service not started" % (took, before[u]["MainPID"],
                                                    after[u]["MainPID"],
                                                    running.get(int(after[u]["MainPID"]))))


def case_upgrade_instance():
    """The same upgrade (upgrade_socket): jakagw@a, started by hand, is
    restarted once on the new binary and serves 1502."""
    up = state.get("upgrade2")
    check(up, "not run: upgrade_socket did not upgrade")
    u = "jakagw@a.service"
    before, after = up["before"][u], up["after"][u]
    check(after["ActiveState"] == "active" and after["InvocationID"] != before["InvocationID"],
          "%s after the upgrade: %s (before %s)" % (u, after, before))
    check(up["starts"][u] == 1, "%s started %d times" % (u, up["starts"][u]))
    exe = up["running"].get(int(after["MainPID"]), "deleted")
    check("deleted" not in exe, "%s runs the old binary: %s" % (u, up["running"]))
    wait_robot_link(1502)
    check(vm().py("result = ir(1502, 0)[0]") == MAGIC, "1502 after the upgrade")
    vm().sh("systemctl stop jakagw@a.service")
    figure("upgrade_instance: jakagw@a restarted once (pid %s -> %s, %s)"
           % (before["MainPID"], after["MainPID"], exe))


def case_both_enabled():
    """jakagw.service and jakagw-socket.service both enabled (socket mode
    switched on by its command, the default never disabled): after each of
    two reboots, one gateway, the socket service, serving 502 through
    systemd's socket; jakagw.service not started."""
    v = vm()
    if not active("jakagw-socket.service"):
        socket_mode()
    for unit in ("jakagw.service", "jakagw-socket.service"):
        check(v.rc("test -L /etc/systemd/system/multi-user.target.wants/%s" % unit)[0] == 0,
              "%s is not enabled" % unit)
    seen = []
    for boot in (1, 2):
        took = v.reboot()
        wait_vm(lambda: active("jakagw-socket.service"), 60,
                "jakagw-socket.service after reboot %d (units: %s)" % (
                    boot, v.sh("systemctl list-units --all --no-legend 'jakagw*'")))
        p = show("jakagw-socket.service", "MainPID")
        running = gateways()
        check(list(running) == [int(p["MainPID"])],
              "boot %d: jakagw processes %s, the socket service's %s" % (boot, running,
                                                                         p["MainPID"]))
        check(not active("jakagw.service"), "boot %d: jakagw.service active" % boot)
        ss = v.sh("ss -ltnpH 'sport = :502'")
        check("systemd" in ss, "boot %d: 502 is not systemd's socket: %s" % (boot, ss))
        wait_robot_link()
        seen.append("boot %d (%.0f s): jakagw-socket.service pid %s alone" % (
            boot, took, p["MainPID"]))
    figure("both_enabled: " + "; ".join(seen))


def nothing_left(ports=(502, 802, 1502)):
    """No jakagw process, no port of a gateway listening, no unit active."""
    v = vm()
    check(not gateways(), "jakagw still runs: %s" % gateways())
    listening = [p for p in listening_ports() if p in ports]
    check(not listening, "still listening on %s" % listening)
    units = v.sh("systemctl list-units --no-legend --plain --state=active,activating 'jakagw*'",
                 ok=None).strip()
    check(not units, "units still active: %s" % units)


def case_remove():
    """dpkg -r with socket mode and an instance running: no jakagw process
    is left and nothing listens on 502, 802 or 1502. (The default mode's
    removal is purge's: a purge runs the same prerm first.) The package
    installed again, socket mode is back as it was."""
    v = vm()
    if not active("jakagw-socket.service"):
        socket_mode()
    start_instance()
    t0 = time.monotonic()
    v.sh("dpkg -r jakagw", timeout=300)
    took = time.monotonic() - t0
    nothing_left()
    v.sh("dpkg -i %s" % v.sh("ls /root/debs/*+upgrade2.deb").strip(), timeout=300)
    check(active("jakagw-socket.service"), "socket mode not back after the reinstall")
    figure("remove: dpkg -r in %.1f s with jakagw-socket.service and jakagw@a running: nothing "
           "left running or listening" % took)


def case_purge():
    """jakagw@a enabled with systemctl and jakagw.service running (the
    default mode, by its documented command back from socket mode), then
    apt purge: nothing runs or listens (prerm's removal), no enablement is left (jakagw@a's
    too), nor a file of the package or of its dynamic user. A reinstall
    enables jakagw.service alone, which stays down (the packaged file names
    no robot), and nothing else starts or is enabled."""
    v = vm()
    if not active("jakagw.service"):
        v.sh("systemctl disable jakagw-socket.service && systemctl restart jakagw.service",
             timeout=120)
    wait_robot_link()
    start_instance()
    v.sh("systemctl enable jakagw@a.service")
    v.sh("DEBIAN_FRONTEND=noninteractive apt-get purge -y jakagw", timeout=300)
    nothing_left()
    # deb-systemd-helper's records too, a previous release's (its sockets
    # had an [Install] of their own; upgrade_from_previous ran it).
    left = v.sh("ls -d /lib/systemd/system/jakagw* /etc/jakagw /var/lib/jakagw "
                "/var/lib/private/jakagw /run/systemd/generator*/jakagw* "
                "/usr/sbin/jakagw 2>/dev/null; find /etc/systemd/system "
                "/var/lib/systemd/deb-systemd-helper-enabled "
                "/var/lib/systemd/deb-systemd-helper-masked -name 'jakagw*'",
                ok=None).split()
    check(not left, "left after purge: %s" % left)
    units = v.sh("systemctl list-units --all --no-legend 'jakagw*'", ok=None).strip()
    check(not units or "not-found" in units and "active" not in units.replace("inactive", ""),
          "units after purge: %s" % units)
    owned = v.sh("find / -xdev \\( -uid +61183 -a -uid -65520 \\) -print 2>/dev/null | head",
                 ok=None).strip()
    check(not owned, "files of a dynamic user: %s" % owned)
    first = v.sh("ls /root/debs/jakagw_*.deb | grep -v upgrade").strip()
    v.sh("dpkg -i %s" % first, timeout=300)
    enabled = v.sh("find /etc/systemd/system -name 'jakagw*'").split()
    check(enabled == ["/etc/systemd/system/multi-user.target.wants/jakagw.service"],
          "enabled after the reinstall: %s" % enabled)
    check(not gateways() and v.sh("systemctl is-enabled jakagw@a.service", ok=None).strip()
          != "enabled", "after the reinstall: running %s" % gateways())
    check(v.rc("test -e /etc/jakagw/a.conf")[0] != 0, "a.conf came back")
    figure("purge: nothing left running, enabled or on disk; the reinstall enabled %s alone "
           "and started nothing" % enabled)


def case_generator():
    """jakagw-generator, in one daemon-reload: a device that is no serial
    port (/dev/mem, an instance's file) gets no drop-in and a journal line;
    a FIFO among the files the check of jakagw.conf reads is bounded (its
    journal line, the reload not held). Run with no output folder it fails
    and writes nothing."""
    v = vm()
    c = mark()
    v.write("/etc/jakagw/probe.conf", conf_with(state["conf"], {
        "rtu": {"enabled": "true", "device": "/dev/mem"}}))
    v.sh("mkfifo /etc/jakagw/hang.pem")
    try:
        set_conf({"rtu": {"enabled": "true", "device": "/dev/ttyS1"},
                  "tls": {"enabled": "true", "certificate": "/etc/jakagw/hang.pem",
                          "private_key": "/etc/jakagw/hang.pem",
                          "client_ca": "/etc/jakagw/hang.pem"}})
        t0 = time.monotonic()
        v.sh("systemctl daemon-reload", timeout=120)
        took = time.monotonic() - t0
        made = v.sh("ls /run/systemd/generator/", ok=None).split()
    finally:
        v.sh("rm -f /etc/jakagw/hang.pem /etc/jakagw/probe.conf")
    check("jakagw@probe.service.d" not in made and "jakagw.service.d" not in made,
          "drop-ins for /dev/mem or past the FIFO: %s" % made)
    said = lambda: [e.get("MESSAGE") for e in journal("-t jakagw-generator", c)]  # noqa: E731
    mem = wait_vm(lambda: [m for m in said() if "/dev/mem" in str(m)], 10,
                  "the generator's line for /dev/mem (it said %s)" % said())
    fifo = wait_vm(lambda: [m for m in said() if "did not finish" in str(m)], 10,
                   "the generator's line for the FIFO (it said %s)" % said())
    check(took < 20, "daemon-reload took %.1f s with a FIFO" % took)
    before = v.sh("ls -A /tmp")
    code, out = v.rc("/lib/systemd/system-generators/jakagw-generator")
    check(code != 0 and "usage" in out, "no argument: exit %d, %r" % (code, out))
    check(v.sh("ls -A /tmp") == before, "it wrote into /tmp")
    # The file as jakagw.service runs it, and the generator's output again.
    set_conf({})
    v.sh("systemctl daemon-reload")
    figure("generator: %r; FIFO: daemon-reload %.1f s, %r; no argument: exit %d"
           % (mem[0], took, fifo[0], code))


# ---- the units decide with the gateway's parser; upgrades keep serving ----

DROPIN_DIR = "/etc/systemd/system/%s.d"


def dropin(unit, text):
    """A local drop-in for 'unit', as 'systemctl edit' writes it (None:
    removed), then daemon-reload."""
    v = vm()
    path = DROPIN_DIR % unit + "/override.conf"
    if text is None:
        v.sh("rm -f %s; rmdir %s 2>/dev/null; systemctl daemon-reload" % (path, DROPIN_DIR % unit))
    else:
        v.sh("mkdir -p %s" % DROPIN_DIR % unit)
        v.write(path, text)
        v.sh("systemctl daemon-reload")


def robot_flag_dropin(flags):
    return "[Service]\nExecStart=\nExecStart=/usr/sbin/jakagw -c /etc/jakagw/jakagw.conf %s\n" \
        % flags


def start_outcome(unit="jakagw.service", verb="restart"):
    """systemctl restart's exit status and systemd's view after it:
    ('active' | 'skipped' | 'failed', details)."""
    v = vm()
    code, out = v.rc("systemctl %s %s" % (verb, unit), timeout=60)
    p = show(unit, "ActiveState", "Result", "ExecMainStatus")
    if p["ActiveState"] == "active":
        return "active", p
    if p["ActiveState"] == "failed":
        failed = v.sh("systemctl --failed --no-legend --plain", ok=None)
        return ("failed" if unit in failed else "failed, not listed"), dict(p, rc=code, out=out)
    return ("skipped" if p["Result"] == "exec-condition" and code == 0 else "other"), \
        dict(p, rc=code, out=out)


def condition_line(unit, after):
    """What the start condition said in the journal."""
    return [str(e.get("MESSAGE")) for e in journal("-u %s" % unit, after)
            if "names no robot" in str(e.get("MESSAGE", "")) or
            "cannot start" in str(e.get("MESSAGE", "")) or
            "configuration error" in str(e.get("MESSAGE", ""))]


def case_condition_parser():
    """The units' start condition is the gateway's parser with the unit's
    own command line: 'host: X' (the parser takes the colon), an indented
    host line, a drop-in adding --robot-host, a drop-in naming another file
    with -c all start the gateway; a commented host with a [roles] line
    'host = read' is a skip (no robot), its reason in the journal."""
    v = vm()
    packaged = state["packaged"]
    other = "/etc/jakagw/other.conf"
    spellings = [
        ("'host: 127.0.0.1'", packaged.replace(";host = 192.0.2.10", "host: 127.0.0.1"), None,
         "active"),
        ("an indented host line", packaged.replace(";host = 192.0.2.10", "  host = 127.0.0.1"),
         None, "active"),
        ("a drop-in with --robot-host", packaged, robot_flag_dropin("--robot-host 127.0.0.1"),
         "active"),
        ("a drop-in with -c other.conf", packaged,
         "[Service]\nExecStart=\nExecStart=/usr/sbin/jakagw -c %s\n" % other, "active"),
        ("a commented host and [roles] host = read", packaged + "\n[roles]\nhost = read\n",
         None, "skipped"),
    ]
    check(";host = 192.0.2.10" in packaged, "the packaged file's host line changed")
    v.write(other, state["conf"])
    seen = []
    dropped = None
    try:
        for what, text, drop, want in spellings:
            v.write("/etc/jakagw/jakagw.conf", text)
            if drop != dropped:  # one daemon-reload from one drop-in to the next
                dropin("jakagw.service", drop)
                dropped = drop
            c = mark()
            got, p = start_outcome()
            check(got == want, "%s: %s, expected %s: %s\n%s" % (what, got, want, p,
                                                               unit_story("jakagw.service")))
            if want == "skipped":
                why = wait_vm(lambda: condition_line("jakagw.service", c), 10,
                              "the skip's reason in the journal")
                check(show("jakagw.service", "MainPID")["MainPID"] == "0",
                      "%s: jakagw.service runs a process" % what)
                seen.append("%s: skipped (%r)" % (what, why[0][:90]))
            else:
                # Active is READY (Type=notify): the gateway parsed its file,
                # bound 502 and runs.
                seen.append("%s: %s" % (what, got))
    finally:
        v.sh("rm -f %s" % other)
        if dropped:
            dropin("jakagw.service", None)
    restore()
    wait_robot_link()
    figure("condition_parser: " + "; ".join(seen))


def case_failure_is_failure():
    """What stops a start is a failure, listed by systemctl --failed, never
    a skip: a configuration file of mode 0600 (the service's user cannot
    read it), an instance with no file, a bad value."""
    v = vm()
    seen = []
    set_conf({})  # a file that names the robot
    v.sh("chmod 0600 /etc/jakagw/jakagw.conf")
    try:
        got, p = start_outcome()
    finally:
        v.sh("chmod 0644 /etc/jakagw/jakagw.conf")
    check(got == "failed", "mode 0600: %s: %s\n%s" % (got, p, unit_story("jakagw.service")))
    seen.append("mode 0600: %s (status %s)" % (got, p["ExecMainStatus"]))
    got, p = start_outcome("jakagw@nosuchname.service", "start")
    check(got == "failed", "an instance without a file: %s: %s" % (got, p))
    seen.append("jakagw@nosuchname: %s" % got)
    c = mark()
    set_conf({"modbus": {"port": "99999"}})
    got, p = start_outcome()
    check(got == "failed", "a bad value: %s: %s" % (got, p))
    said = condition_line("jakagw.service", c)
    check(any("port" in m for m in said), "no line names the bad key: %s" % said)
    seen.append("[modbus] port = 99999: %s (%r)" % (got, said[0][:80]))
    v.sh("systemctl reset-failed 'jakagw*'", ok=None)
    set_conf({})  # the next case starts the gateway on it
    figure("failure_is_failure: " + "; ".join(seen))


def case_serial_port_taken():
    """jakagw.conf and an instance's file both name /dev/ttyS1: the
    generator says so in the journal at the daemon-reload; the gateway that
    opens it first has it, the second refuses to start with a clear line
    (failed, not restarted)."""
    v = vm()
    v.sh("systemctl stop 'jakagw@*.service'", timeout=60)
    c = mark()
    set_conf({"rtu": {"enabled": "true", "device": "/dev/ttyS1"}})
    v.write("/etc/jakagw/a.conf", conf_with(state["conf"], {
        "modbus": {"port": "1502"}, "rtu": {"enabled": "true", "device": "/dev/ttyS1"}}))
    restart(daemon_reload=True)
    warned = wait_vm(lambda: [e.get("MESSAGE") for e in journal("-t jakagw-generator", c)
                              if "both name the serial port" in str(e.get("MESSAGE"))], 10,
                     "the generator's line about one port in two files")
    wait_vm(lambda: "rtu: /dev/ttyS1" in v.sh("journalctl --no-pager -o cat -u jakagw.service "
                                              "-n 30"), 10, "jakagw.service's line open")
    got, p = start_outcome("jakagw@a.service", "start")
    check(got == "failed", "the second gateway on /dev/ttyS1: %s: %s\n%s"
          % (got, p, unit_story("jakagw@a.service")))
    lines = [str(e.get("MESSAGE")) for e in journal("-u jakagw@a.service", c)
             if "taken" in str(e.get("MESSAGE"))]
    check(lines, "no line says the port is taken: %s" % unit_story("jakagw@a.service"))
    check(active("jakagw.service"), "the first gateway stopped")
    # by_id_links, next, sets up the files and drop-ins again.
    v.sh("rm -f /etc/jakagw/a.conf; systemctl reset-failed jakagw@a.service", ok=None)
    figure("serial_port_taken: generator %r; jakagw@a failed: %r" % (warned[0][:100],
                                                                     lines[0][:100]))


def case_by_id_links():
    """A /dev/serial/by-id link that loops (jakagw.conf) and one that leads
    nowhere (an instance's file), in one daemon-reload: no drop-in for
    either, a journal line each, and both gateways start and serve Modbus
    TCP (a loop bound into the unit failed it, TCP side too)."""
    v = vm()
    loop, dangling = "/dev/serial/by-id/usb-jakagw-test-loop", \
        "/dev/serial/by-id/usb-jakagw-test-gone"
    v.sh("mkdir -p /dev/serial/by-id && ln -sfn %s %s && ln -sfn /dev/ttyUSB9 %s"
         % (loop, loop, dangling))
    c = mark()
    try:
        set_conf({"rtu": {"enabled": "true", "device": loop}})
        v.write("/etc/jakagw/a.conf", conf_with(state["conf"], {
            "modbus": {"port": "1502"}, "rtu": {"enabled": "true", "device": dangling}}))
        restart(daemon_reload=True)
        made = v.sh("ls /run/systemd/generator/", ok=None).split()
        check("jakagw.service.d" not in made and "jakagw@a.service.d" not in made,
              "a drop-in for a link that leads nowhere: %s" % made)
        said = wait_vm(lambda: [str(e.get("MESSAGE")) for e in journal("-t jakagw-generator", c)
                                if "leads nowhere" in str(e.get("MESSAGE"))], 10,
                       "the generator's lines for the two links")
        check(len(said) >= 2, "one line for two links: %s" % said)
        wait_robot_link()
        start_instance()
        check(v.py("result = ir(1502, 0)[0]") == MAGIC, "1502 beside a dangling link")
    finally:
        v.sh("systemctl stop jakagw@a.service; rm -f %s %s /etc/jakagw/a.conf" % (loop, dangling),
             ok=None)
    restore(daemon_reload=True)
    figure("by_id_links: no drop-in, %d journal lines (%r); 502 and 1502 served"
           % (len(said), said[0][:100]))


def case_socket_unconfigured():
    """Socket mode enabled with the packaged file (no robot named): no port
    is opened (502 and 802 refused, the sockets not started), the generator
    says why; with the robot named, a daemon-reload and a restart, 502 is
    served. Ends in socket mode."""
    v = vm()
    v.sh("systemctl stop jakagw-socket.service jakagw.socket jakagw-mbaps.socket", timeout=60)
    c = mark()
    v.write("/etc/jakagw/jakagw.conf", state["packaged"])
    v.sh("systemctl daemon-reload")
    code, out = v.rc("systemctl enable --now jakagw-socket.service", timeout=120)
    ports = listening_ports()
    check(502 not in ports and 802 not in ports, "listening with no robot named: %s" % ports)
    check(refused(502), "a connection to 502 was accepted")
    check(not gateways(), "a gateway runs: %s" % gateways())
    for sock in ("jakagw.socket", "jakagw-mbaps.socket"):
        check(not active(sock), "%s is active" % sock)
    said = wait_vm(lambda: [str(e.get("MESSAGE")) for e in journal("-t jakagw-generator", c)
                            if "gets no socket" in str(e.get("MESSAGE"))], 10,
                   "the generator's line")
    v.write("/etc/jakagw/jakagw.conf", state["conf"])
    v.sh("systemctl daemon-reload")
    restart("jakagw-socket.service")
    wait_robot_link()
    # The socket restarts while its service runs (the service with it).
    code2, out2 = v.rc("systemctl restart jakagw.socket", timeout=60)
    check(code2 == 0, "systemctl restart jakagw.socket: %s" % out2)
    wait_robot_link()
    figure("socket_unconfigured: enable --now exit %d; listening %s, 502 refused; %r; named: "
           "502 served; restart jakagw.socket while it serves: exit %d, 502 served again"
           % (code, ports, said[0][:100], code2))


def case_writes_until_allowed():
    """The packaged file with the robot named, nothing else changed: a PLC
    reads the map, but its write is refused (exception 01) and nothing
    reaches the robot; the journal and the status page say who may write.
    With [modbus] write_allow naming the PLC, its write reaches the robot
    once."""
    v = vm()
    c = mark()
    v.write("/etc/jakagw/jakagw.conf", conf_with(state["packaged"], {
        "robot": {"host": "127.0.0.1"}, "http": {"enabled": "true"}}))
    restart()
    wait_robot_link()
    check(v.py("result = ir(502, 0)[0]") == MAGIC, "a read with the packaged write_allow")
    got = v.py("result = pulse(502, %d)" % COIL_POWER_ON)
    check(got == [1, 1], "writes with the packaged write_allow: %s" % got)
    time.sleep(1)
    check(not delivered(after=c), "delivered: %s" % delivered(after=c))
    said = [str(e.get("MESSAGE")) for e in journal("-u jakagw.service", c)
            if "Modbus writes" in str(e.get("MESSAGE"))]
    check(said and "no Modbus TCP client" in said[-1], "the journal: %s" % said)
    page = json.loads(v.sh("python3 -c \"import urllib.request; print(urllib.request.urlopen("
                           "'http://127.0.0.1:10502/status.json').read().decode())\""))
    shown = page["gateway"].get("modbus_writes", "")
    check("no Modbus TCP client" in shown, "the status page: %r" % shown)
    c2 = mark()
    v.write("/etc/jakagw/jakagw.conf", conf_with(state["packaged"], {
        "robot": {"host": "127.0.0.1"}, "modbus": {"write_allow": "127.0.0.1"}}))
    restart()
    wait_robot_link()
    check(v.py("result = pulse(502, %d)" % COIL_POWER_ON) == [0, 0], "a named PLC's write")
    wait_vm(lambda: len(sim_commands(after=c2, name="power_on")) == 1, 10, "power_on")
    set_conf({})  # the next case starts the gateway on it
    figure("writes_until_allowed: packaged write_allow: read served, write exception 01, "
           "nothing delivered; journal %r; status page %r; named 127.0.0.1: power_on once"
           % (said[-1][:90], shown[:60]))


def install_previous():
    """The previous release's package (PREVIOUS of make-service-image.py)
    installed over this one as its own file was, never edited (its
    postinst restarts jakagw.service, with the drop-ins in place)."""
    v = vm()
    v.sh("dpkg -i --force-confnew --force-downgrade /root/debs/previous.deb", timeout=300)
    version = v.sh("dpkg-query -W -f='${Version}' jakagw")
    check("~" in version, "the previous release is not installed: %s" % version)
    shipped = v.sh("dpkg-query -W -f='${Conffiles}' jakagw").split()
    md5 = v.sh("md5sum < /etc/jakagw/jakagw.conf").split()[0]
    check(md5 in shipped and "host = 127.0.0.1" in v.sh("cat /etc/jakagw/jakagw.conf"),
          "jakagw.conf is not the previous package's own file: %s %s" % (md5, shipped))
    return version


def upgrade_as_unattended(with_apt):
    """The upgrade as unattended-upgrades runs it: no question, an edited
    conffile kept, an unedited one replaced (dpkg's --force-confdef
    --force-confold, through apt, or dpkg itself, which applies them).
    Its time, a journal mark before it, what it printed."""
    v = vm()
    c = mark()
    t0 = time.monotonic()
    deb = v.sh("ls /root/debs/*+upgrade2.deb").strip()
    if with_apt:
        cmd = ("DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "
               "-o Dpkg::Options::=--force-confdef -o Dpkg::Options::=--force-confold %s" % deb)
    else:
        cmd = "dpkg -i --force-confdef --force-confold %s" % deb
    code, out = v.rc(cmd + " 2>&1", timeout=300)
    check(code == 0, "the upgrade failed: %s" % out[-2000:])
    return time.monotonic() - t0, c, out


def served_after_upgrade(unit, c):
    """After an upgrade from the previous release: 'unit' runs the new
    binary and serves 502; jakagw.conf still names its robot and takes
    writes from any client, as it did, with the gateway's warning; a PLC's
    power_on reaches the robot once."""
    v = vm()
    wait_vm(lambda: active(unit), 30, "%s after the upgrade: %s" % (unit, unit_story(unit)))
    exe = gateways().get(int(show(unit, "MainPID")["MainPID"]), "none")
    check("deleted" not in exe and exe != "none", "%s runs %s" % (unit, exe))
    wait_robot_link()
    conf = v.sh("cat /etc/jakagw/jakagw.conf")
    check(re.search(r"^host = 127\.0\.0\.1$", conf, re.M), "jakagw.conf lost its robot")
    check(re.search(r"^write_allow =$", conf, re.M), "write_allow narrowed: %s" % [
        line for line in conf.splitlines() if "write_allow" in line])
    warned = [str(e.get("MESSAGE")) for e in journal("-u %s" % unit, c)
              if "Modbus writes from any client" in str(e.get("MESSAGE"))]
    check(warned, "no warning that any client may write")
    before = mark()
    check(v.py("result = pulse(502, %d)" % COIL_POWER_ON) == [0, 0], "a PLC's write after")
    wait_vm(lambda: len(sim_commands(after=before, name="power_on")) == 1, 10, "power_on")


def case_upgrade_from_previous():
    """The previous release (commit PREVIOUS, built from it) as a plant ran
    it: its own jakagw.conf never edited, the robot named in a drop-in
    (--robot-host, as its jakagw(8) allowed), in the default mode and then
    in socket mode; each upgraded as unattended-upgrades does (apt, then
    dpkg, --force-confdef --force-confold). After each, the same service
    serves 502 on the new binary, jakagw.conf still names its robot and
    takes writes from any client (with a warning), and a PLC's write
    reaches the robot. Ends in socket mode."""
    v = vm()
    import importlib.util
    spec = importlib.util.spec_from_file_location(
        "msi", os.path.join(ROOT, "scripts", "make-service-image.py"))
    msi = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(msi)
    seen = []
    # Default mode: the drop-in and the mode in place before the previous
    # package goes in, whose postinst then reloads and restarts them.
    t0 = time.monotonic()
    v.sh("systemctl disable --now jakagw-socket.service", timeout=120)
    v.sh("mkdir -p %s" % DROPIN_DIR % "jakagw.service")
    v.write(DROPIN_DIR % "jakagw.service" + "/override.conf",
            robot_flag_dropin("--robot-host 127.0.0.1"))
    previous = install_previous()
    wait_vm(lambda: active("jakagw.service"), 30, "the previous release's jakagw.service")
    wait_robot_link()
    set_up = time.monotonic() - t0
    took, c, out = upgrade_as_unattended(with_apt=True)
    served_after_upgrade("jakagw.service", c)
    told = [line for line in out.splitlines() if line.startswith("jakagw: ")]
    seen.append("default mode: %s installed and serving in %.1f s, apt upgrade to +upgrade2 in "
                "%.1f s, jakagw.service serving after (%s)" % (previous, set_up, took,
                                                              "; ".join(told)[:160]))
    # Socket mode, by the previous release's own command
    # (its docs/service.md), the drop-in the socket service's.
    t0 = time.monotonic()
    v.sh("rm -rf %s" % DROPIN_DIR % "jakagw.service")
    v.sh("mkdir -p %s" % DROPIN_DIR % "jakagw-socket.service")
    v.write(DROPIN_DIR % "jakagw-socket.service" + "/override.conf",
            robot_flag_dropin("--robot-host 127.0.0.1"))
    install_previous()
    v.sh("systemctl disable --now jakagw; systemctl enable --now jakagw-socket.service",
         timeout=120)
    wait_robot_link()
    set_up = time.monotonic() - t0
    took, c, out = upgrade_as_unattended(with_apt=False)
    served_after_upgrade("jakagw-socket.service", c)
    seen.append("socket mode: set up in %.1f s, dpkg upgrade in %.1f s, jakagw-socket.service "
                "serving after" % (set_up, took))
    v.sh("rm -rf %s" % DROPIN_DIR % "jakagw-socket.service")
    figure("upgrade_from_previous (commit %s): %s" % (msi.PREVIOUS, " | ".join(seen)))

def case_seccomp():
    """Every case ran under the units' SystemCallFilter: no SIGSYS and no
    'audit: type=1326' line in the whole boot (the probe's aside)."""
    check("seccomp_exclude" in state, "not run: the detector's probe failed")
    found = seccomp_kills(state["seccomp_exclude"])
    check(not found, "filtered system calls:\n" + "\n".join(found))
    figure("seccomp: no SIGSYS, no audit type=1326 in the boot (the detector saw the probe's)")


def main():
    missing = [t for t in ("mmdebstrap", "qemu-system-x86_64", "mbpoll", "mke2fs", "dpkg-deb")
               if not shutil.which(t, path=os.environ.get("PATH", "") + ":/usr/sbin:/sbin")]
    if os.geteuid() != 0 or missing:
        print("service VM test skipped: %s" % ("needs root" if os.geteuid() != 0
                                               else "missing %s: make deps" % " ".join(missing)))
        print("0 passed, 0 failed")
        return
    os.makedirs(VMDIR, exist_ok=True)
    start = time.monotonic()
    try:
        run_all()
    finally:
        if "vm" in state:
            state["vm"].stop()
        print("service VM test: %.0f s in all" % (time.monotonic() - start))


def run_all():
    cases = [case_boot, case_fresh_install, case_ready, case_reload, case_watchdog, case_socket,
             case_instances, case_credential, case_journal, case_tls_only, case_credential_rtu,
             case_rtu, case_can, case_generator, case_condition_parser, case_failure_is_failure,
             case_writes_until_allowed, case_serial_port_taken, case_by_id_links, case_upgrade,
             case_upgrade_socket, case_upgrade_instance, case_both_enabled,
             case_socket_unconfigured, case_upgrade_from_previous, case_remove, case_purge, case_seccomp]
    only = os.environ.get("JAKAGW_SERVICE_CASES")
    if only:
        cases = [c for c in cases if c is case_boot or c.__name__[5:] in only.split()]
    try:
        run(cases)
    except SystemExit:
        print("figures:")
        for f in FIGURES:
            print("  " + f)
        raise


if __name__ == "__main__":
    main()
