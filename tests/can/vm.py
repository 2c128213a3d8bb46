# SPDX-License-Identifier: MIT
"""A Debian kernel booted in qemu (TCG, no KVM) from an initramfs built here,
for the tests that need a real kernel's CAN stack or traffic control.

The initramfs holds busybox-static, the kernel modules a test names (with
what they need, in order), the build's programs and every shared library ldd
lists for them, and the test's /init script. What the script prints on the
serial console comes back parsed: "@@event NAME UPTIME" lines, "@@exit PROG
CODE" lines, "@@error ..." lines (any fails the run), files sent gzipped and
base64-encoded between "@@begin NAME" and "@@end NAME", and "@@done" last.

Used by test_can_vm.py and test_netem_vm.py.
"""
import base64
import glob
import gzip
import io
import lzma
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, "..", ".."))
sys.path.insert(0, os.path.join(ROOT, "tests", "integration"))

from harness import TestFailure, check  # noqa: E402

# The start of every /init: busybox's applets, the file systems, quiet
# kernel messages, an "event" function and the modules loaded.
INIT_HEAD = r"""#!/bin/busybox sh
/bin/busybox --install -s /bin
export PATH=/bin:/usr/bin:/sbin:/usr/sbin
mount -t proc proc /proc
mount -t sysfs sys /sys
mount -t devtmpfs dev /dev
mount -t tmpfs tmp /tmp
echo 1 > /proc/sys/kernel/printk
echo  # the firmware's last line has no end
event() { echo "@@event $1 $(cut -d' ' -f1 /proc/uptime)"; }
for m in @MODULES@; do insmod /lib/modules/test/$m.ko || echo "@@error insmod $m"; done
ip link set lo up
"""

# The end of every /init: the files sent back, then power off.
INIT_TAIL = r"""
cd /tmp
for f in @FILES@; do
    [ -f "$f" ] || continue
    echo "@@begin $f"; gzip -c $f | base64; echo "@@end $f"
done
echo "@@done"
poweroff -f
"""


def find_kernel():
    """The newest /boot/vmlinuz-VERSION with its /lib/modules/VERSION."""
    for path in sorted(glob.glob("/boot/vmlinuz-*"), reverse=True):
        version = path[len("/boot/vmlinuz-"):]
        if os.path.exists("/lib/modules/%s/modules.dep" % version):
            return path, version
    raise TestFailure("no /boot/vmlinuz-* with modules: apt-get install linux-image-amd64")


def _module_name(path):
    return re.sub(r"\.ko(\.\w+)?$", "", os.path.basename(path)).replace("_", "-")


def module_order(version, modules):
    """'modules' and what they need, dependencies first: (name, path)."""
    base = "/lib/modules/%s" % version
    paths, deps = {}, {}
    with open(os.path.join(base, "modules.dep")) as f:
        for line in f:
            target, _, needs = line.partition(":")
            name = _module_name(target)
            paths[name] = os.path.join(base, target)
            deps[name] = [_module_name(n) for n in needs.split()]
    order = []

    def visit(name):
        if name in order:
            return
        if name not in paths:
            raise TestFailure("kernel %s has no module %s" % (version, name))
        for d in deps[name]:
            visit(d)
        order.append(name)

    for m in modules:
        visit(m)
    return [(m, paths[m]) for m in order]


def module_bytes(path):
    with open(path, "rb") as f:
        data = f.read()
    if path.endswith(".xz"):
        return lzma.decompress(data)
    if path.endswith(".ko"):
        return data
    raise TestFailure("cannot unpack module %s" % path)


def shared_libraries(binary):
    """Every library ldd lists for 'binary', and its program interpreter."""
    out = subprocess.run(["ldd", binary], capture_output=True, text=True)
    if "not a dynamic executable" in out.stdout + out.stderr:
        return []
    check(out.returncode == 0, "ldd %s: %s" % (binary, out.stderr))
    libs = []
    for line in out.stdout.splitlines():
        m = re.search(r"(/\S+) \(0x", line)
        if m:
            libs.append(m.group(1))
    return libs


class Cpio:
    """A newc cpio archive, as the kernel unpacks an initramfs."""

    def __init__(self):
        self.out = io.BytesIO()
        self.ino = 1
        self.dirs = set()

    def _entry(self, name, mode, data=b"", nlink=1):
        name_b = name.encode() + b"\0"
        header = "070701" + "".join("%08X" % v for v in (
            self.ino, mode, 0, 0, nlink, 0, len(data), 0, 0, 0, 0, len(name_b), 0))
        self.ino += 1
        self.out.write(header.encode() + name_b)
        self.out.write(b"\0" * (-(110 + len(name_b)) % 4))
        self.out.write(data)
        self.out.write(b"\0" * (-len(data) % 4))

    def directory(self, path):
        path = path.strip("/")
        parts = path.split("/")
        for i in range(1, len(parts) + 1):
            d = "/".join(parts[:i])
            if d and d not in self.dirs:
                self.dirs.add(d)
                self._entry(d, 0o040755, nlink=2)

    def file(self, path, data, mode=0o644):
        path = path.strip("/")
        self.directory(os.path.dirname(path))
        self._entry(path, 0o100000 | mode, data)

    def symlink(self, path, target):
        path = path.strip("/")
        self.directory(os.path.dirname(path))
        self._entry(path, 0o120777, target.encode())

    def finish(self):
        self._entry("TRAILER!!!", 0)
        return self.out.getvalue()


class Initramfs:
    """An initramfs under construction: busybox, programs with their
    libraries, kernel modules, files and the /init script."""

    def __init__(self, version):
        self.version = version
        self.cpio = Cpio()
        self.added = set()
        self.modules = []
        for d in ("proc", "sys", "dev", "tmp", "usr/bin", "usr/sbin"):
            self.cpio.directory(d)
        self.program(shutil.which("busybox") or "/bin/busybox", "/bin/busybox")

    def program(self, src, dest):
        """A program and every shared library it needs."""
        with open(src, "rb") as f:
            self.cpio.file(dest, f.read(), 0o755)
        for lib in shared_libraries(src):
            if lib in self.added:
                continue
            self.added.add(lib)
            with open(os.path.realpath(lib), "rb") as f:
                self.cpio.file(lib, f.read(), 0o755)

    def tool(self, name, dest_dir="/usr/bin"):
        """An installed program found on PATH (or in /sbin, /usr/sbin)."""
        path = shutil.which(name, path=os.environ.get("PATH", "") + ":/usr/sbin:/sbin")
        check(path, "%s is not installed (make deps)" % name)
        self.program(path, dest_dir + "/" + name)

    def kernel_modules(self, names):
        for name, path in module_order(self.version, names):
            self.cpio.file("/lib/modules/test/%s.ko" % name, module_bytes(path))
            self.modules.append(name)

    def file(self, path, data, mode=0o644):
        self.cpio.file(path, data if isinstance(data, bytes) else data.encode(), mode)

    def init(self, body, files):
        """/init: INIT_HEAD, the test's 'body', then 'files' (in /tmp) sent back."""
        script = (INIT_HEAD.replace("@MODULES@", " ".join(self.modules)) + body
                  + INIT_TAIL.replace("@FILES@", " ".join(files)))
        self.cpio.file("/init", script.encode(), 0o755)

    def image(self):
        return gzip.compress(self.cpio.finish(), compresslevel=1)


class VmRun:
    """What a VM run printed: files, events (uptime), exits, the console."""

    def __init__(self):
        self.files = {}
        self.events = {}
        self.exits = {}
        self.console = ""
        self.wall_s = 0.0


def boot(kernel, image, timeout_s, keep_env, memory_mb=512):
    """Boots 'kernel' with the initramfs 'image' and returns a VmRun; the
    run fails on a timeout, an @@error line or a missing @@done."""
    qemu = shutil.which("qemu-system-x86_64")
    check(qemu, "qemu-system-x86_64 is not installed (make deps)")
    work = tempfile.mkdtemp(prefix="jakagw-vm-")
    initrd = os.path.join(work, "initrd.gz")
    with open(initrd, "wb") as f:
        f.write(image)
    argv = [qemu, "-accel", "tcg", "-nographic", "-m", str(memory_mb),
            "-smp", os.environ.get("JAKAGW_CAN_SMP", "2"), "-no-reboot",
            "-nic", "none", "-kernel", kernel, "-initrd", initrd,
            "-append", "console=ttyS0 quiet loglevel=3 panic=-1"]
    start = time.monotonic()
    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        shutil.rmtree(work, True)
        raise TestFailure("the VM did not finish within %d s; console:\n%s"
                          % (timeout_s, out.decode(errors="replace")[-3000:]))
    r = VmRun()
    r.wall_s = time.monotonic() - start
    r.console = out.decode(errors="replace").replace("\r", "")
    if os.environ.get(keep_env) == "1":
        with open(os.path.join(work, "console.txt"), "w") as f:
            f.write(r.console)
        print("  work directory: %s" % work)
    else:
        shutil.rmtree(work)
    name, chunks = None, []
    for line in r.console.splitlines():
        if line.startswith("@@begin "):
            name, chunks = line.split()[1], []
        elif line.startswith("@@end ") and name:
            r.files[name] = gzip.decompress(base64.b64decode("".join(chunks))).decode(
                errors="replace")
            name = None
        elif name:
            chunks.append(line.strip())
        elif line.startswith("@@event "):
            _, what, uptime = line.split()
            r.events[what] = float(uptime)
        elif line.startswith("@@exit "):
            _, prog, code = line.split()
            r.exits[prog] = int(code)
    errors = [l for l in r.console.splitlines() if l.startswith("@@error")]
    check(not errors and "@@done" in r.console,
          "the VM run failed: %s\nconsole:\n%s" % (errors, r.console[-3000:]))
    return r


def candump_frames(text):
    """(time, interface, id, data) from candump -L lines."""
    frames = []
    for line in text.splitlines():
        m = re.match(r"\((\d+\.\d+)\) (\S+) ([0-9A-F]+)#([0-9A-F]*)$", line.strip())
        if m:
            frames.append((float(m.group(1)), m.group(2), int(m.group(3), 16),
                           bytes.fromhex(m.group(4))))
    return frames


def ensure_cantools(script):
    """Runs 'script' again under a venv that has cantools (from PyPI, made
    once under the build directory), unless cantools imports already."""
    try:
        import cantools  # noqa: F401
        return
    except ImportError:
        pass
    from harness import BIN
    venv = os.path.abspath(os.environ.get("JAKAGW_CAN_VENV", os.path.join(BIN, "can-venv")))
    python = os.path.join(venv, "bin", "python")
    if os.environ.get("JAKAGW_CAN_IN_VENV") == "1":
        raise SystemExit("cantools is missing from %s" % venv)
    if not os.path.exists(python):
        print("making a venv with cantools in %s" % venv, flush=True)
        subprocess.run([sys.executable, "-m", "venv", venv], check=True)
    ok = subprocess.run([python, "-c", "import cantools"], capture_output=True).returncode == 0
    if not ok:
        subprocess.run([python, "-m", "pip", "install", "-q", "--disable-pip-version-check",
                        "cantools"], check=True)
    env = dict(os.environ, JAKAGW_CAN_IN_VENV="1")
    os.execve(python, [python, os.path.abspath(script)] + sys.argv[1:], env)
