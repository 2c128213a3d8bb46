#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The Debian package, as an administrator meets it: built with make deb
(dpkg-buildpackage), checked by lintian, installed with apt into a fresh
Debian 12 root filesystem made by mmdebstrap (the mechanism CI uses, which
also works inside CI's own chroot), then upgraded twice over a local edit of
the configuration, removed and purged. Every unit is checked with
systemd-analyze verify and rated with systemd-analyze security.

  tests/package/test_package.py [BUILD_DIR]     (make test-package)

For an ARM build (JAKAGW_ARCH=arm64|armhf, as make test ARCH=... sets it),
the package is cross-built (make deb ARCH=...) and checked where it is:
Architecture, Depends computed against the sysroot, lintian, the ELF
machine of its binaries, which then run under qemu-user from the unpacked
package. Installing it with apt into a root filesystem of that
architecture would run ARM maintainer scripts, which needs binfmt_misc
(this machine and CI have none): the amd64 run checks the installation.

Needs root (mmdebstrap --mode=root, chroot), mmdebstrap, debhelper,
lintian and systemd: 'make deps' installs them (group 'package').
"""
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
from harness import TestFailure, check, run  # noqa: E402

BUILD = sys.argv[1] if len(sys.argv) > 1 else "build"
ARCH = os.environ.get("JAKAGW_ARCH", "")
# ELF class and machine of each architecture's binaries.
ELF_MACHINE = {"arm64": (2, 183), "armhf": (1, 40), "amd64": (2, 62)}
QEMU = {"arm64": "qemu-aarch64", "armhf": "qemu-arm"}
TRIPLET = {"arm64": "aarch64-linux-gnu", "armhf": "arm-linux-gnueabihf"}
UNITS = ["jakagw.service", "jakagw@.service", "jakagw.socket", "jakagw-socket.service",
         "jakagw-mbaps.socket"]
# What systemd-analyze security may rate each service, at most.
EXPOSURE_LIMITS = {"jakagw.service": 1.9, "jakagw@cell1.service": 1.9,
                   "jakagw-socket.service": 1.2}
state = {}


def sh(argv, timeout=600, ok=(0,), **kw):
    r = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, **kw)
    if r.returncode not in ok:
        raise TestFailure("%s: exit %d\n%s%s" % (" ".join(argv), r.returncode,
                                                  r.stdout[-3000:], r.stderr[-3000:]))
    return r


def makefile_version():
    with open(os.path.join(ROOT, "Makefile")) as f:
        return re.search(r"^VERSION\s*:=\s*(\S+)", f.read(), re.M).group(1)


def in_root(*argv, ok=(0,), stdin=subprocess.DEVNULL):
    return sh(["chroot", need("root"), "env", "-i", "PATH=/usr/sbin:/usr/bin:/sbin:/bin",
               "LANG=C.UTF-8", "DEBIAN_FRONTEND=noninteractive"] + list(argv), ok=ok,
              stdin=stdin)


def need(key):
    """What an earlier step made, or a failure that says it is missing."""
    if key not in state:
        raise TestFailure("not run: an earlier step failed (no %s)" % key)
    return state[key]


def rootpath(path):
    return os.path.join(need("root"), path.lstrip("/"))


def conf_text():
    with open(rootpath("/etc/jakagw/jakagw.conf")) as f:
        return f.read()


def repack(version, conf_extra=None):
    """The built package again, as another version: an upgrade to install."""
    work = tempfile.mkdtemp(dir=need("work"))
    sh(["dpkg-deb", "-R", need("deb"), work])
    control = os.path.join(work, "DEBIAN", "control")
    with open(control) as f:
        text = re.sub(r"^Version: .*$", "Version: " + version, f.read(), flags=re.M)
    with open(control, "w") as f:
        f.write(text)
    if conf_extra:
        with open(os.path.join(work, "etc", "jakagw", "jakagw.conf"), "a") as f:
            f.write(conf_extra)
    name = "jakagw_%s.deb" % version
    sh(["dpkg-deb", "--root-owner-group", "-b", work, rootpath("/tmp/" + name)])
    shutil.rmtree(work)
    return "/tmp/" + name


def test_make_deb_builds_the_package():
    """make deb, without the unit tests a package build runs (make test has
    run them already)."""
    start = time.monotonic()
    options = (os.environ.get("DEB_BUILD_OPTIONS", "") + " nocheck").strip()
    r = sh(["make", "-s", "-C", ROOT, "BUILD=" + BUILD, "deb"] + (["ARCH=" + ARCH] if ARCH else []),
           timeout=900, env=dict(os.environ, DEB_BUILD_OPTIONS=options))
    deb = r.stdout.strip().splitlines()[-1]
    check(deb.endswith(".deb") and os.path.isfile(deb), "make deb printed %r" % r.stdout)
    state["deb"] = deb
    state["changes"] = deb[:-len(".deb")] + ".changes"
    version = sh(["dpkg-deb", "-f", deb, "Version"]).stdout.strip()
    check(version == makefile_version(),
          "package version %s, Makefile VERSION %s" % (version, makefile_version()))
    print("  built %s in %.0f s" % (os.path.basename(deb), time.monotonic() - start))


def test_package_contents():
    deb = need("deb")
    listing = sh(["dpkg-deb", "-c", deb]).stdout
    files = {line.split()[-1].lstrip(".") for line in listing.splitlines()}
    want = ["/usr/sbin/jakagw", "/usr/bin/jakasim", "/etc/jakagw/jakagw.conf",
            "/usr/share/man/man8/jakagw.8.gz", "/usr/share/man/man1/jakasim.1.gz",
            "/usr/share/doc/jakagw/copyright"]
    want += ["/lib/systemd/system/" + u for u in UNITS]
    want.append("/lib/systemd/system-generators/jakagw-generator")
    want.append("/usr/libexec/jakagw/jakagw-condition")
    for doc in ["README.md", "register-map.md", "register-map.csv", "plc-guide.md",
                "jakagw.dbc"]:
        if doc == "README.md" or os.path.exists(os.path.join(ROOT, "docs", doc)):
            want.append("/usr/share/doc/jakagw/" + ("" if doc == "README.md" else "docs/") + doc)
    for path in want:
        check(path in files or path + ".gz" in files, "%s is not in the package" % path)
    conffiles = sh(["dpkg-deb", "-I", deb, "conffiles"]).stdout.split()
    check(conffiles == ["/etc/jakagw/jakagw.conf"], "conffiles: %s" % conffiles)
    depends = sh(["dpkg-deb", "-f", deb, "Depends"]).stdout
    for lib in ["libuv1", "libmodbus5", "libcjson1", "libinih1", "libsystemd0", "libssl3",
                "libc6", "procps"]:
        check(lib in depends, "Depends lacks %s: %s" % (lib, depends))
    arch = sh(["dpkg-deb", "-f", deb, "Architecture"]).stdout.strip()
    want_arch = ARCH or sh(["dpkg", "--print-architecture"]).stdout.strip()
    check(arch == want_arch, "Architecture: %s, expected %s" % (arch, want_arch))
    print("  %s: Architecture: %s; Depends: %s" % (os.path.basename(deb), arch, depends.strip()))


def test_lintian_finds_no_error():
    r = sh(["lintian", "--info", "--display-info", "--pedantic", "--tag-display-limit", "0",
            need("changes")], ok=(0, 1, 2), timeout=600)
    tags = [l for l in r.stdout.splitlines() if re.match(r"^[EWIPX]: ", l)]
    counts = {k: sum(1 for t in tags if t.startswith(k + ":")) for k in "EWIP"}
    print("  lintian (pedantic): %d errors, %d warnings, %d info, %d pedantic"
          % (counts["E"], counts["W"], counts["I"], counts["P"]))
    for t in tags:
        print("    " + t)
    check(counts["E"] == 0, "lintian errors:\n" + "\n".join(t for t in tags if t[0] == "E"))
    check(counts["W"] == 0, "lintian warnings:\n" + "\n".join(t for t in tags if t[0] == "W"))
    check("error" not in r.stderr.lower() or counts["E"] == 0, r.stderr)


def elf_class_machine(path):
    with open(path, "rb") as f:
        head = f.read(20)
    check(head[:4] == b"\x7fELF", "%s is not an ELF file" % path)
    return head[4], int.from_bytes(head[18:20], "little")


def test_arm_package_depends_come_from_the_sysroot():
    """Every library package in Depends is one of the sysroot's, and each
    library the binaries need (DT_NEEDED) is in it: dpkg-shlibdeps found
    them there, nothing was written by hand."""
    sysroot = os.path.join(ROOT, BUILD, "sysroot")
    with open(os.path.join(sysroot, ".jakagw-packages")) as f:
        packages = {line.split()[0] for line in f if line.strip()}
    depends = sh(["dpkg-deb", "-f", need("deb"), "Depends"]).stdout
    names = {d.strip().split()[0] for d in depends.split(",")} - {"procps"}
    check(names and names <= packages,
          "Depends names packages not in the sysroot: %s" % sorted(names - packages))
    # Which sysroot package ships each soname: the first line of its
    # section in the symbols files (soname package #MINVER#).
    provider = {}
    with open(os.path.join(sysroot, "DEBIAN", "symbols")) as f:
        for line in f:
            if line[:1] not in (" ", "|", "*", "#", "") and len(line.split()) >= 2:
                provider.setdefault(line.split()[0], line.split()[1])
    work = tempfile.mkdtemp(prefix="jakagw-package-%s." % ARCH, dir="/var/tmp")
    try:
        sh(["dpkg-deb", "-x", need("deb"), work])
        for path in ("usr/sbin/jakagw", "usr/bin/jakasim"):
            dynamic = sh([TRIPLET[ARCH] + "-objdump", "-p", os.path.join(work, path)]).stdout
            for soname in re.findall(r"^\s*NEEDED\s+(\S+)", dynamic, re.M):
                check(provider.get(soname) in names,
                      "%s needs %s (package %s), not in Depends: %s"
                      % (path, soname, provider.get(soname), depends))
    finally:
        shutil.rmtree(work)


def test_arm_binaries_run_under_qemu():
    """The packaged binaries are ARCH's, stripped, and run under qemu-user
    with the sysroot's libraries: --version, and --check-config of the
    packaged configuration."""
    work = tempfile.mkdtemp(prefix="jakagw-package-%s." % ARCH, dir="/var/tmp")
    state["work"] = work
    sh(["dpkg-deb", "-x", need("deb"), work])
    sysroot = os.path.join(ROOT, BUILD, "sysroot")
    runner = [QEMU[ARCH], "-L", sysroot]
    sizes = []
    for path in ("usr/sbin/jakagw", "usr/bin/jakasim"):
        full = os.path.join(work, path)
        check(elf_class_machine(full) == ELF_MACHINE[ARCH],
              "%s: ELF class and machine %s, expected %s" % (path, elf_class_machine(full),
                                                            ELF_MACHINE[ARCH]))
        sections = sh([TRIPLET[ARCH] + "-objdump", "-h", full]).stdout
        check(".debug_info" not in sections, "%s is not stripped" % path)
        sizes.append("%s %d bytes" % (os.path.basename(path), os.path.getsize(full)))
    print("  stripped, %s: %s" % (ARCH, ", ".join(sizes)))
    r = sh(runner + [os.path.join(work, "usr/sbin/jakagw"), "--version"])
    check(r.stdout.startswith("jakagw " + makefile_version()), r.stdout)
    r = sh(runner + [os.path.join(work, "usr/sbin/jakagw"), "-c",
                     os.path.join(work, "etc/jakagw/jakagw.conf"), "--check-config"])
    check("[modbus]" in r.stdout, r.stdout)
    r = sh(runner + [os.path.join(work, "usr/bin/jakasim"), "--help"])
    check("--status-port" in r.stdout, r.stdout)


def apt_sources():
    """This machine's Debian apt sources, as CI passes them to mmdebstrap."""
    for path in ("/etc/apt/sources.list.d/debian.sources",
                 "/etc/apt/sources.list.d/0000debian.sources", "/etc/apt/sources.list"):
        if os.path.isfile(path) and os.path.getsize(path) > 0:
            return [path]
    return []


def test_installs_into_a_fresh_debian_12():
    """apt installs the .deb, pulling its dependencies, into a fresh root
    filesystem with systemd: the units are in place and jakagw.service is
    enabled, the others are not; the installed binary runs."""
    start = time.monotonic()
    deb = need("deb")
    work = tempfile.mkdtemp(prefix="jakagw-package.", dir="/var/tmp")
    state["work"] = work
    root = os.path.join(work, "root")
    # A throwaway root: dpkg skips its fsyncs there (the install itself is
    # the same).
    sh(["mmdebstrap", "--mode=root", "--variant=apt", "--include=systemd",
        "--dpkgopt=force-unsafe-io",
        "--customize-hook=copy-in %s /tmp" % deb,
        "--customize-hook=chroot \"$1\" env DEBIAN_FRONTEND=noninteractive "
        "apt-get install -y --no-install-recommends /tmp/%s" % os.path.basename(deb),
        "bookworm", root] + apt_sources(), timeout=900)
    state["root"] = root
    print("  mmdebstrap and apt-get install: %.0f s" % (time.monotonic() - start))
    check(os.access(rootpath("/usr/sbin/jakagw"), os.X_OK), "/usr/sbin/jakagw")
    for unit in UNITS:
        check(os.path.isfile(rootpath("/lib/systemd/system/" + unit)), unit)
    wants = rootpath("/etc/systemd/system/multi-user.target.wants")
    check(os.path.islink(os.path.join(wants, "jakagw.service")), "jakagw.service not enabled")
    for unit in ("jakagw-socket.service", "jakagw@.service"):
        check(not os.path.lexists(os.path.join(wants, unit)), "%s enabled" % unit)
    check(not os.path.lexists(rootpath("/etc/systemd/system/sockets.target.wants/jakagw.socket")),
          "jakagw.socket enabled")
    r = in_root("/usr/sbin/jakagw", "--version")
    check(r.stdout.startswith("jakagw " + makefile_version()), r.stdout)
    r = in_root("/usr/sbin/jakagw", "--check-config")
    check("[modbus]" in r.stdout and "no configuration file" not in r.stdout, r.stdout)
    with open(rootpath("/lib/systemd/system/jakagw.service")) as f:
        unit = f.read()
    check("ExecStart=/usr/sbin/jakagw -c /etc/jakagw/jakagw.conf" in unit, unit)
    check("file:///usr/share/doc/jakagw/README.md" in unit, "Documentation=: " + unit)
    check(os.path.isfile(rootpath("/usr/share/doc/jakagw/README.md.gz"))
          or os.path.isfile(rootpath("/usr/share/doc/jakagw/README.md")), "README")


def test_installed_man_pages_render_without_warnings():
    for page in ("/usr/share/man/man8/jakagw.8.gz", "/usr/share/man/man1/jakasim.1.gz"):
        r = sh(["man", "--warnings", "-l", rootpath(page)], env=dict(os.environ, MANWIDTH="80"))
        check(r.stderr == "", "%s: %s" % (page, r.stderr))
        check(len(r.stdout.splitlines()) > 40, "%s is short: %s" % (page, r.stdout))


def test_units_verify():
    r = sh(["systemd-analyze", "verify", "--man=no", "--root=" + need("root"),
            "jakagw.service", "jakagw@cell1.service", "jakagw.socket",
            "jakagw-socket.service"], ok=(0, 1))
    check(r.returncode == 0 and r.stdout.strip() == "" and r.stderr.strip() == "",
          "systemd-analyze verify: %s%s" % (r.stdout, r.stderr))


def test_units_exposure():
    scores = []
    for unit, limit in EXPOSURE_LIMITS.items():
        r = sh(["systemd-analyze", "security", "--offline=true", "--root=" + need("root"),
                unit], ok=(0, 1))
        m = re.search(r"Overall exposure level for %s: ([0-9.]+)" % re.escape(unit), r.stdout)
        check(m, "%s: no rating: %s %s" % (unit, r.stdout[-500:], r.stderr))
        scores.append("%s %s" % (unit, m.group(1)))
        check(float(m.group(1)) <= limit, "%s rates %s, above %s" % (unit, m.group(1), limit))
    print("  systemd-analyze security: " + ", ".join(scores))


def generate(*args):
    """jakagw-generator as systemd runs it (here without /dev/kmsg, so its
    lines go to stderr): what it wrote into a fresh output folder, and what
    it said."""
    shutil.rmtree(rootpath("/tmp/gen"), ignore_errors=True)
    os.makedirs(rootpath("/tmp/gen"))
    r = in_root("/lib/systemd/system-generators/jakagw-generator", *(args or (
        "/tmp/gen", "/tmp/gen.early", "/tmp/gen.late")), ok=(0, 2))
    made = []
    for dirpath, dirnames, filenames in os.walk(rootpath("/tmp/gen")):
        made += [os.path.relpath(os.path.join(dirpath, n), rootpath("/tmp/gen"))
                 for n in filenames]
    return sorted(made), r


def test_packaged_configuration_names_no_robot():
    """The installed file leaves [robot] host commented out (the units'
    ExecCondition= then skips them: the gateway's parser says so with exit
    status 1) and takes writes from no plain Modbus TCP client (write_allow
    = none), and is otherwise config/jakagw.conf."""
    with open(os.path.join(ROOT, "config", "jakagw.conf")) as f:
        shipped = f.read()
    text = conf_text()
    check(not re.search(r"^host\s*=", text, re.M) and re.search(r"^;host = ", text, re.M),
          "the packaged file names a robot")
    check(re.search(r"^write_allow = none$", text, re.M), "the packaged file takes writes")
    check([l for l in text.splitlines() if not l.startswith(";")] ==
          [l.replace("write_allow =", "write_allow = none") for l in shipped.splitlines()
           if not l.startswith(";") and not l.startswith("host =")],
          "the packaged file differs in more than [robot] host and [modbus] write_allow")
    for unit in ("jakagw.service", "jakagw-socket.service", "jakagw@.service"):
        with open(rootpath("/lib/systemd/system/" + unit)) as f:
            check("ExecCondition=+/usr/libexec/jakagw/jakagw-condition %n /usr/sbin/jakagw -c "
                  in f.read(), "%s has no ExecCondition= by the gateway's parser" % unit)
    r = in_root("/usr/sbin/jakagw", "-c", "/etc/jakagw/jakagw.conf", "--check-start", ok=(1,))
    check("names no robot" in r.stderr, "--check-start: %s" % r.stderr)


def test_generator_follows_the_rtu_device():
    """jakagw-generator, run as systemd runs it, writes a drop-in giving
    jakagw@cell1 the one serial port its file's [rtu] device names (a by-id
    name's ':' escaped for BindPaths=), and none for jakagw.service, whose
    file leaves [rtu] disabled; the socket service gets no socket while
    jakagw.conf names no robot (as packaged), and once it names one the
    sockets of its file (502 alone: [tls] is off)."""
    device = "/dev/serial/by-id/usb-FTDI_FT232R_A1-0000:00:14.0-1-if00-port0"
    conf = rootpath("/etc/jakagw/cell1.conf")
    with open(conf, "w") as f:
        f.write("[rtu]\nenabled = true\ndevice = %s\n" % device)
    try:
        made, _ = generate()
        device_unit = sh(["systemd-escape", "--path", "--suffix=device", device]).stdout.strip()
        check(made == sorted(["jakagw@cell1.service.d/50-jakagw-rtu.conf",
                              device_unit + ".d/50-jakagw-rtu.conf",
                              "jakagw-socket.service.d/50-jakagw-sockets.conf"]),
              "drop-ins %s" % made)
        with open(rootpath("/tmp/gen/%s.d/50-jakagw-rtu.conf" % device_unit)) as f:
            check("JobRunningTimeoutSec=10s" in f.read(), "no bounded wait for the device")
        with open(rootpath("/tmp/gen/jakagw@cell1.service.d/50-jakagw-rtu.conf")) as f:
            text = f.read()
        for line in ("BindPaths=-" + device.replace(":", "\\:"), "DeviceAllow=%s rw" % device,
                     "SupplementaryGroups=dialout", "After=dev-serial-by\\x2did-usb"):
            check(line in text, "%r not in the drop-in:\n%s" % (line, text))
        with open(rootpath("/tmp/gen/jakagw-socket.service.d/50-jakagw-sockets.conf")) as f:
            sockets = re.findall(r"^Sockets=(.*)$", f.read(), re.M)
        check(sockets == [], "sockets with no robot named: %s" % sockets)
        packaged = conf_text()
        with open(rootpath("/etc/jakagw/jakagw.conf"), "w") as f:
            f.write(packaged.replace(";host = 192.0.2.10", "host = 192.0.2.10"))
        try:
            generate()
        finally:
            with open(rootpath("/etc/jakagw/jakagw.conf"), "w") as f:
                f.write(packaged)
        with open(rootpath("/tmp/gen/jakagw-socket.service.d/50-jakagw-sockets.conf")) as f:
            sockets = re.findall(r"^Sockets=(.*)$", f.read(), re.M)
        check(sockets == ["jakagw.socket"], "the socket service's sockets: %s" % sockets)
    finally:
        os.remove(conf)
        shutil.rmtree(rootpath("/tmp/gen"), ignore_errors=True)


def test_generator_grants_serial_ports_only():
    """Devices that are not serial ports get no drop-in and a line saying
    so; with no output folder the generator fails and writes nothing."""
    conf = rootpath("/etc/jakagw/cell1.conf")
    try:
        for device in ("/dev/mem", "/dev/sda", "/dev/kvm", "/dev/serial/by-id/../../mem",
                       "/dev/ttyS1/../mem"):
            with open(conf, "w") as f:
                f.write("[rtu]\nenabled = true\ndevice = %s\n" % device)
            made, r = generate()
            check(not [m for m in made if "rtu" in m], "%s: drop-ins %s" % (device, made))
            check(device in r.stderr and "cell1" in r.stderr, "%s: said %r" % (device, r.stderr))
            # Nothing written outside the output folder: here, no /dev/kmsg
            # file made where the root has no such device.
            check(not os.path.exists(rootpath("/dev/kmsg")) or
                  not os.path.isfile(rootpath("/dev/kmsg")), "the generator made a /dev/kmsg file")
    finally:
        os.remove(conf)
    _, r = generate("")
    check(r.returncode == 2 and "usage" in r.stderr, "no folder: %s %r" % (r.returncode, r.stderr))
    r = in_root("/lib/systemd/system-generators/jakagw-generator", ok=(2,))
    check("usage" in r.stderr, r.stderr)
    shutil.rmtree(rootpath("/tmp/gen"), ignore_errors=True)


def test_upgrades_keep_a_local_edit():
    """An edit survives an upgrade that ships the same configuration file
    silently; when the new version ships a changed one, dpkg asks (and, with
    no answer, changes nothing), and keeping the edit leaves the new
    default beside it as jakagw.conf.dpkg-dist."""
    path = rootpath("/etc/jakagw/jakagw.conf")
    edited = conf_text().replace("\nport = 502\n", "\nport = 1502\n") + "; local edit\n"
    check("port = 1502" in edited, "no 'port = 502' line to edit")
    with open(path, "w") as f:
        f.write(edited)

    same = repack(makefile_version() + "+test1")
    in_root("dpkg", "-i", same)
    check(conf_text() == edited, "the upgrade changed the edited configuration")
    left = sorted(os.listdir(rootpath("/etc/jakagw")))
    check(left == ["jakagw.conf"], "left in /etc/jakagw: %s" % left)

    changed = repack(makefile_version() + "+test2", "; a new default\n")
    r = in_root("dpkg", "-i", changed, ok=(1,))
    check("conffile prompt" in r.stderr and "Configuration file '/etc/jakagw/jakagw.conf'"
          in r.stdout + r.stderr,
          "dpkg did not ask about the configuration: %s%s" % (r.stdout, r.stderr))
    check(conf_text() == edited, "an unanswered question changed the configuration")
    in_root("dpkg", "--configure", "-a", "--force-confold")
    check(conf_text() == edited, "--force-confold did not keep the edit")
    with open(rootpath("/etc/jakagw/jakagw.conf.dpkg-dist")) as f:
        check(f.read().endswith("; a new default\n"), "jakagw.conf.dpkg-dist")
    version = in_root("dpkg-query", "-W", "-f=${Version} ${Status}", "jakagw").stdout
    check(version == makefile_version() + "+test2 install ok installed", version)
    wants = rootpath("/etc/systemd/system/multi-user.target.wants/jakagw.service")
    check(os.path.islink(wants), "jakagw.service no longer enabled after the upgrades")


def test_remove_keeps_the_configuration_and_purge_removes_it():
    """Without systemd running (dpkg's paths alone): remove keeps the
    configuration; purge removes it, the instances' files and every
    enablement, jakagw@NAME's made with systemctl too."""
    wants = rootpath("/etc/systemd/system/multi-user.target.wants")
    os.symlink("/lib/systemd/system/jakagw@.service", os.path.join(wants, "jakagw@cell1.service"))
    with open(rootpath("/etc/jakagw/cell1.conf"), "w") as f:
        f.write("[robot]\nhost = 10.0.0.1\n")
    in_root("dpkg", "-r", "jakagw")
    check(not os.path.exists(rootpath("/usr/sbin/jakagw")), "removed, /usr/sbin/jakagw stays")
    check(os.path.isfile(rootpath("/etc/jakagw/jakagw.conf")), "remove deleted the configuration")
    in_root("dpkg", "-P", "jakagw")
    check(not os.path.exists(rootpath("/etc/jakagw/jakagw.conf")), "purge left the configuration")
    check(not os.path.lexists(rootpath("/etc/systemd/system/multi-user.target.wants/"
                                       "jakagw.service")), "purge left the unit enabled")
    left = sh(["find", rootpath("/etc/systemd/system"), rootpath("/etc/jakagw"), "-name",
               "jakagw*", "-o", "-name", "cell1*"], ok=(0, 1)).stdout.split()
    check(not left, "purge left %s" % left)


def cleanup():
    work = state.get("work")
    if not work:
        return
    # mmdebstrap unmounts what it mounted; never remove through a mount.
    with open("/proc/self/mounts") as f:
        mounted = [line.split()[1] for line in f if work in line.split()[1]]
    if mounted:
        print("  not removing %s: still mounted: %s" % (work, mounted))
        return
    shutil.rmtree(work, ignore_errors=True)


def main():
    missing = [tool for tool in ("mmdebstrap", "dpkg-buildpackage", "dh", "lintian",
                                 "systemd-analyze", "chroot", "man")
               if not shutil.which(tool)]
    if os.geteuid() != 0 or missing:
        print("package test skipped: %s" % ("needs root" if os.geteuid() != 0 else
                                            "missing %s: make deps" % " ".join(missing)))
        print("0 passed, 0 failed")
        return
    start = time.monotonic()
    import atexit
    atexit.register(lambda: print("package test: %.0f s in all" % (time.monotonic() - start)))
    if ARCH:
        try:
            run([test_make_deb_builds_the_package, test_package_contents,
                 test_arm_package_depends_come_from_the_sysroot, test_lintian_finds_no_error,
                 test_arm_binaries_run_under_qemu])
        finally:
            cleanup()
    try:
        run([test_make_deb_builds_the_package, test_package_contents,
             test_lintian_finds_no_error, test_installs_into_a_fresh_debian_12,
             test_installed_man_pages_render_without_warnings, test_units_verify,
             test_units_exposure, test_packaged_configuration_names_no_robot,
             test_generator_follows_the_rtu_device, test_generator_grants_serial_ports_only,
             test_upgrades_keep_a_local_edit,
             test_remove_keeps_the_configuration_and_purge_removes_it])
    finally:
        cleanup()


if __name__ == "__main__":
    main()
