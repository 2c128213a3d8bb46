#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""What make install and the units give an administrator: every unit passes
systemd-analyze verify and rates low in systemd-analyze security; make
install puts each file where its PREFIX says and never overwrites a
configuration; the man pages are what the code says and render cleanly.
The Debian package has its own test (tests/package, make test-package)."""
import os
import re
import shutil
import subprocess
import tempfile

from harness import BIN, TestFailure, check, run

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
UNITS = ["jakagw.service", "jakagw@.service", "jakagw.socket", "jakagw-socket.service",
         "jakagw-mbaps.socket"]
# The most systemd-analyze security may rate each service.
EXPOSURE_LIMITS = {"jakagw.service": 1.9, "jakagw@.service": 1.9, "jakagw-socket.service": 1.2}


def filled_units(directory, sbindir):
    """The unit templates with the paths filled in as make install does
    (their start condition, jakagw-condition, beside them)."""
    with open(os.path.join(ROOT, "systemd", "jakagw-condition.in")) as f:
        condition = os.path.join(directory, "jakagw-condition")
        with open(condition, "w") as out:
            out.write(f.read().replace("@SBINDIR@", sbindir))
        os.chmod(condition, 0o755)
    for unit in UNITS:
        with open(os.path.join(ROOT, "systemd", unit + ".in")) as f:
            text = f.read()
        text = (text.replace("@SBINDIR@", sbindir).replace("@SYSCONFDIR@", "/etc")
                .replace("@DOCDIR@", "/usr/share/doc/jakagw").replace("@LIBEXECDIR@", directory))
        check(not re.search(r"@[A-Z]+@", text), "%s: a path left unfilled" % unit)
        with open(os.path.join(directory, unit), "w") as f:
            f.write(text)


def need(tool):
    if not shutil.which(tool):
        raise TestFailure("%s is not installed: run make deps" % tool)


def test_units_verify():
    need("systemd-analyze")
    with tempfile.TemporaryDirectory() as d:
        # ExecStart= must name an executable that exists: the build's.
        filled_units(d, os.path.abspath(BIN))
        r = subprocess.run(["systemd-analyze", "verify", "--man=no"]
                           + [os.path.join(d, u) for u in UNITS],
                           capture_output=True, text=True, timeout=60)
    check(r.returncode == 0 and not r.stdout.strip() and not r.stderr.strip(),
          "systemd-analyze verify: exit %d: %s%s" % (r.returncode, r.stdout, r.stderr))


def test_units_exposure():
    need("systemd-analyze")
    scores = []
    with tempfile.TemporaryDirectory() as d:
        filled_units(d, "/usr/sbin")
        for unit, limit in EXPOSURE_LIMITS.items():
            r = subprocess.run(["systemd-analyze", "security", "--offline=true",
                                os.path.join(d, unit)], capture_output=True, text=True,
                               timeout=60)
            m = re.search(r"Overall exposure level for \S+: ([0-9.]+)", r.stdout)
            check(m, "%s: no rating: %s %s" % (unit, r.stdout[-500:], r.stderr))
            scores.append("%s %s" % (unit, m.group(1)))
            check(float(m.group(1)) <= limit, "%s rates %s, above %s" % (unit, m.group(1), limit))
    print("  systemd-analyze security: " + ", ".join(scores))


def test_units_restart_forever_and_reload():
    for unit in ("jakagw.service", "jakagw@.service", "jakagw-socket.service"):
        with open(os.path.join(ROOT, "systemd", unit + ".in")) as f:
            text = f.read()
        for line in ("StartLimitIntervalSec=0", "Restart=always", "RestartSec=2s",
                     "RestartPreventExitStatus=2 226", "ExecReload=/bin/kill -HUP $MAINPID",
                     "Type=notify", "WatchdogSec=10s", "DynamicUser=yes"):
            check(line in text.splitlines(), "%s lacks %s" % (unit, line))


def test_start_condition_without_systemd():
    """The units' start condition (jakagw-condition, as make install fills
    it) where systemd does not answer for the unit (none runs here, and the
    unit does not exist): checked with the package's command line, by the
    gateway's parser; 1 (a skip, the reason on stderr) only when no robot
    is named, 0 otherwise, a bad value included (ExecStart= fails it); a
    command line of another program is not checked."""
    with tempfile.TemporaryDirectory() as d:
        filled_units(d, os.path.abspath(BIN))
        jakagw = os.path.join(os.path.abspath(BIN), "jakagw")
        files = {"none": "[robot]\n;host = 192.0.2.10\n", "named": "[robot]\nhost = 127.0.0.1\n",
                 "bad": "[robot]\nhost = 127.0.0.1\n[modbus]\nport = 99999\n"}
        for name, text in files.items():
            with open(os.path.join(d, name + ".conf"), "w") as f:
                f.write(text)
        unit = "jakagw-no-such-unit.service"
        cases = [
            ([jakagw, "-c", os.path.join(d, "none.conf")], 1, "names no robot"),
            ([jakagw, "-c", os.path.join(d, "none.conf"), "--robot-host", "127.0.0.1"], 0, None),
            ([jakagw, "-c", os.path.join(d, "named.conf")], 0, None),
            ([jakagw, "-c", os.path.join(d, "bad.conf")], 0, None),
            ([jakagw, "-c", os.path.join(d, "none.conf"), "--no-such-flag"], 0, None),
            (["/bin/true", "-c", os.path.join(d, "none.conf")], 0, "not this jakagw"),
        ]
        for command, want, said in cases:
            r = subprocess.run([os.path.join(d, "jakagw-condition"), unit] + command,
                               capture_output=True, text=True, timeout=30)
            check(r.returncode == want, "%s: exit %d, expected %d: %s"
                  % (command[1:], r.returncode, want, r.stderr))
            check("systemd did not say how %s runs" % unit in r.stderr,
                  "%s: no line says the package's command line was checked: %s" % (command, r.stderr))
            check(not r.stdout, "%s: printed %r" % (command, r.stdout))
            lines = [l for l in r.stderr.splitlines() if "did not say" not in l]
            if said:
                check(any(said in l for l in lines), "%s: %r not said: %s" % (command, said, r.stderr))
            else:
                check(not lines, "%s: said %s (ExecStart= says it)" % (command, lines))


def sanitizer_pass():
    """make install builds what it installs: in the sanitizer build's pass it
    would rebuild stale objects without the sanitizers, so it runs in the
    plain build's pass only."""
    if os.path.basename(os.path.normpath(BIN)).endswith("-san"):
        print("  make install is tested in the plain build's pass")
        return True
    return False


def make(*args):
    r = subprocess.run(["make", "-s", "-C", ROOT, "BUILD=" + os.path.relpath(BIN, ROOT)]
                       + list(args), capture_output=True, text=True, timeout=300)
    check(r.returncode == 0, "make %s: %s%s" % (" ".join(args), r.stdout, r.stderr[-2000:]))
    return r.stdout


def read(path):
    with open(path) as f:
        return f.read()


def test_make_install_usr():
    if sanitizer_pass():
        return
    with tempfile.TemporaryDirectory() as stage:
        make("install", "DESTDIR=" + stage, "PREFIX=/usr")
        for f in ["usr/sbin/jakagw", "usr/bin/jakasim", "etc/jakagw/jakagw.conf",
                  "usr/share/man/man8/jakagw.8", "usr/share/man/man1/jakasim.1",
                  "usr/share/doc/jakagw/README.md", "usr/share/doc/jakagw/docs/register-map.md",
                  "usr/share/doc/jakagw/docs/register-map.csv", "usr/share/doc/jakagw/docs/rtu.md"] + \
                ["lib/systemd/system/" + u for u in UNITS]:
            check(os.path.isfile(os.path.join(stage, f)), "%s not installed" % f)
        check(os.access(os.path.join(stage, "usr/sbin/jakagw"), os.X_OK), "not executable")
        unit = read(os.path.join(stage, "lib/systemd/system/jakagw.service"))
        check("ExecStart=/usr/sbin/jakagw -c /etc/jakagw/jakagw.conf" in unit, unit)
        check("Documentation=man:jakagw(8) file:///usr/share/doc/jakagw/README.md" in unit, unit)
        instance = read(os.path.join(stage, "lib/systemd/system/jakagw@.service"))
        check("ExecStart=/usr/sbin/jakagw -c /etc/jakagw/%i.conf" in instance, instance)
        check("ExecCondition=+/usr/libexec/jakagw/jakagw-condition %n /usr/sbin/jakagw -c "
              "/etc/jakagw/%i.conf" in instance, instance)
        check(os.access(os.path.join(stage, "usr/libexec/jakagw/jakagw-condition"), os.X_OK),
              "the units' start condition is not installed")


def test_make_install_local_keeps_the_configuration():
    """PREFIX=/usr/local: the units go under the prefix and name its
    docdir. A second install over an edited configuration keeps the edit
    and puts the new default beside it; uninstall keeps it too."""
    if sanitizer_pass():
        return
    with tempfile.TemporaryDirectory() as stage:
        make("install", "DESTDIR=" + stage, "PREFIX=/usr/local")
        unitdir = os.path.join(stage, "usr/local/lib/systemd/system")
        for u in UNITS:
            check(os.path.isfile(os.path.join(unitdir, u)), "%s not in %s" % (u, unitdir))
        check(not os.path.exists(os.path.join(stage, "lib")), "units in /lib for /usr/local")
        unit = read(os.path.join(unitdir, "jakagw.service"))
        check("ExecStart=/usr/local/sbin/jakagw -c /etc/jakagw/jakagw.conf" in unit, unit)
        check("file:///usr/local/share/doc/jakagw/README.md" in unit, unit)

        conf = os.path.join(stage, "etc/jakagw/jakagw.conf")
        edited = read(conf).replace("\nport = 502\n", "\nport = 1502\n")
        with open(conf, "w") as f:
            f.write(edited)
        out = make("install", "DESTDIR=" + stage, "PREFIX=/usr/local")
        check(read(conf) == edited, "make install overwrote an edited configuration")
        check(read(conf + ".dist") == read(os.path.join(ROOT, "config", "jakagw.conf")),
              "no jakagw.conf.dist")
        check("exists and is kept" in out, "no message about the kept configuration: " + out)

        out = make("uninstall", "DESTDIR=" + stage, "PREFIX=/usr/local")
        left = sorted(os.path.relpath(os.path.join(d, f), stage)
                      for d, _, files in os.walk(stage) for f in files)
        check(left == ["etc/jakagw/jakagw.conf", "etc/jakagw/jakagw.conf.dist"],
              "uninstall left: %s" % left)
        check("is kept" in out, out)


def test_man_pages_are_current():
    for page in ("jakagw.8", "jakasim.1"):
        r = subprocess.run(["/usr/bin/python3", os.path.join(ROOT, "scripts", "gen-man.py"),
                            BIN, page], capture_output=True, text=True, timeout=60)
        check(r.returncode == 0, "gen-man.py %s: %s" % (page, r.stderr))
        check(r.stdout == read(os.path.join(ROOT, "man", page)),
              "man/%s is not what the code says: run 'make man' and commit it" % page)


def test_man_pages_render_without_warnings():
    need("man")
    for page in ("jakagw.8", "jakasim.1"):
        r = subprocess.run(["man", "--warnings", "-l", os.path.join(ROOT, "man", page)],
                           capture_output=True, text=True, timeout=60,
                           env=dict(os.environ, MANWIDTH="80"))
        check(r.returncode == 0 and r.stderr == "", "man -l %s: %s" % (page, r.stderr))
        for section in ("OPTIONS",) + (("CONFIGURATION", "RELOAD", "SIGNALS", "FILES",
                                        "EXIT STATUS") if page == "jakagw.8" else ()):
            check(re.search(r"^%s$" % section, r.stdout, re.M), "%s: no %s" % (page, section))


if __name__ == "__main__":
    run([test_units_verify, test_units_exposure, test_units_restart_forever_and_reload,
         test_start_condition_without_systemd, test_make_install_usr, test_make_install_local_keeps_the_configuration,
         test_man_pages_are_current, test_man_pages_render_without_warnings])
