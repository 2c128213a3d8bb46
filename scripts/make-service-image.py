#!/usr/bin/env python3
# SPDX-License-Identifier: MIT
"""The disk image of the service VM (tests/service/test_service_vm.py): a
Debian 12 root file system with systemd as PID 1, made by mmdebstrap, with
the jakagw package from 'make deb' installed by apt from the file, as a
plant installs it. Prints the image's path.

  scripts/make-service-image.py OUTDIR DEB

What else is in it, and why:
  - the packages the cases use inside the VM: jakasim is in the package;
    python3-pymodbus (the PLC), can-utils (candump), iproute2 (ip,
    ss), openssl (the TLS case's certificates), kmod, udev (the serial
    ports' /dev/serial/by-id names), dbus, libnss-systemd (dynamic users);
  - this machine's kernel modules (the kernel the VM boots is this
    machine's /boot/vmlinuz, with its stock initrd), those of the drivers
    the cases need: USB serial adapters, virtio, CAN;
  - the test agent (tests/service/agent.py) and its unit, which runs the
    host's commands and sends back what they printed over a virtio serial
    port; jakasim as the robot (robot.service);
  - two newer builds of the same package (VERSION+upgrade1 and +upgrade2,
    repacked from the .deb) in /root/debs for the upgrade cases;
  - the previous release's package, built from its commit (PREVIOUS, the
    main this package's series of changes started from: git archive of
    that commit, its own scripts/build-deb.sh) and given a version below
    this one (VERSION~PREVIOUS), in /root/debs for upgrade_from_previous;
    cached as OUTDIR/previous-PREVIOUS.deb, as the commit never changes
    (needs the repository's history, which CI's clone has);
  - for speed under TCG (DPKG_OPTIONS, UNUSED_DIRS, MASKED_UNITS,
    MASKED_GENERATORS): dpkg without fsync, no other packages'
    translations, manuals and documents, no boot units or generators that
    no case uses, no debconf preconfiguration in apt.

The image is an ext4 file made with mke2fs -d (no loop device, no mount:
this works in CI's chroot), cached as OUTDIR/image-KEY.ext4, KEY a hash of
every input: this script, the agent, the package list, the apt sources,
the .deb and the kernel. The VM boots it with -snapshot, so the cached
file never changes.
"""
import glob
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.abspath(os.path.join(HERE, ".."))
AGENT = os.path.join(ROOT, "tests", "service", "agent.py")

# The previous release: the commit upgrade_from_previous upgrades from.
PREVIOUS = "a7d60e1"
PACKAGES = ["systemd-sysv", "udev", "dbus", "libnss-systemd", "kmod", "iproute2", "can-utils",
            "openssl", "python3", "python3-pymodbus", "python3-serial-asyncio", "procps"]
# dpkg's settings in the image (/etc/dpkg/dpkg.cfg.d/99mmdebstrap), for the
# build and for the upgrade case's apt in the VM: no fsync per file (the VM
# boots a throw-away snapshot).
DPKG_OPTIONS = ["force-unsafe-io"]
# Other packages' translations, manuals and documents, removed from the
# image after the build: fewer files to copy into it and for the purge
# check's find over the whole disk to walk under TCG (a third of its files
# were translations). (dpkg's path-exclude= would keep them out, but made
# mmdebstrap 15 s slower here: 60 s against 45 s.)
UNUSED_DIRS = ["usr/share/locale", "usr/share/man", "usr/share/doc"]
# What systemd starts at boot that no case uses, masked: under TCG each
# costs the boot a fraction of a second, and the utmp records were on the
# critical chain to multi-user.target. (The units of jakagw, udev, dbus,
# journald and the generators a case relies on stay as Debian ships them.)
MASKED_UNITS = ["systemd-update-utmp.service", "systemd-update-utmp-runlevel.service",
                "systemd-logind.service", "modprobe@drm.service", "modprobe@efi_pstore.service",
                "modprobe@fuse.service", "modprobe@loop.service", "modprobe@dm_mod.service",
                "sys-kernel-debug.mount", "sys-kernel-tracing.mount", "dev-hugepages.mount",
                "fstrim.timer", "dpkg-db-backup.timer", "systemd-tmpfiles-clean.timer",
                "e2scrub_all.timer"]
# Generators for what the VM does not have (encrypted or verity disks, a
# GPT disk, hibernation, SysV scripts, rc.local, kernel command line units),
# masked in /etc/systemd/system-generators (systemd.generator(7)): systemd
# runs every generator at each daemon-reload, and the cases and the
# package's maintainer scripts reload a dozen times. jakagw-generator,
# fstab and getty stay.
MASKED_GENERATORS = ["systemd-cryptsetup-generator", "systemd-debug-generator",
                     "systemd-gpt-auto-generator", "systemd-hibernate-resume-generator",
                     "systemd-integritysetup-generator", "systemd-rc-local-generator",
                     "systemd-run-generator", "systemd-system-update-generator",
                     "systemd-sysv-generator", "systemd-veritysetup-generator"]
# Driver directories of this machine's kernel copied into the image (with
# every module they need from elsewhere): USB host controllers and serial
# adapters, serial ports, virtio (the agent's port), CAN and vcan.
MODULE_DIRS = ["drivers/usb", "drivers/tty", "drivers/char", "drivers/virtio",
               "drivers/net/can", "net/can"]
IMAGE_MB = 1536

AGENT_UNIT = """[Unit]
Description=jakagw service test agent (the host's commands over a virtio port)
DefaultDependencies=no
After=systemd-udevd.service

[Service]
ExecStart=/usr/bin/python3 /usr/local/lib/jakagw-test/agent.py /dev/virtio-ports/jakagw.agent
Restart=always
RestartSec=1

[Install]
WantedBy=multi-user.target
"""

# The robot: jakasim on the ports of the packaged configuration, powered
# on with a program running, taking a command connection silent for 3 s as
# lost (as a controller's link check does; the gateway checks its link
# every second, and a VM without KVM needs the margin).
ROBOT_UNIT = """[Unit]
Description=jakasim as the robot of the service test
Before=jakagw.service

[Service]
ExecStart=/usr/bin/jakasim --log-commands --auto-run --link-check-ms 3000
Restart=no

[Install]
WantedBy=multi-user.target
"""


def sh(argv, **kw):
    r = subprocess.run(argv, capture_output=True, text=True, **kw)
    if r.returncode != 0:
        sys.stderr.write("%s: exit %d\n%s%s" % (" ".join(argv), r.returncode, r.stdout[-4000:],
                                                 r.stderr[-4000:]))
        raise SystemExit(1)
    return r.stdout


def kernel():
    """The newest /boot/vmlinuz-VERSION with its initrd and modules."""
    for path in sorted(glob.glob("/boot/vmlinuz-*"), reverse=True):
        version = path[len("/boot/vmlinuz-"):]
        initrd = "/boot/initrd.img-" + version
        if os.path.exists("/lib/modules/%s/modules.dep" % version) and os.path.isfile(initrd):
            return path, initrd, version
    raise SystemExit("make-service-image: no /boot/vmlinuz-* with its initrd and modules: "
                     "apt-get install linux-image-amd64 (make deps)")


def apt_sources():
    for path in ("/etc/apt/sources.list.d/debian.sources", "/etc/apt/sources.list"):
        if os.path.isfile(path) and os.path.getsize(path) > 0:
            return [path]
    return []


def file_hash(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def image_key(deb, version):
    h = hashlib.sha256()
    for path in [os.path.abspath(__file__), AGENT, deb] + apt_sources():
        h.update(file_hash(path).encode())
    h.update(" ".join(PACKAGES + DPKG_OPTIONS + UNUSED_DIRS + MASKED_UNITS + MASKED_GENERATORS +
                      MODULE_DIRS + [version, str(IMAGE_MB), PREVIOUS]).encode())
    return h.hexdigest()[:16]


def module_closure(version):
    """The modules under MODULE_DIRS and what they need: relative paths."""
    base = "/lib/modules/" + version
    deps = {}
    with open(os.path.join(base, "modules.dep")) as f:
        for line in f:
            target, _, needs = line.partition(":")
            deps[target] = needs.split()
    want = [m for m in deps if any(m.startswith("kernel/%s/" % d) for d in MODULE_DIRS)]
    seen = set()
    while want:
        m = want.pop()
        if m not in seen:
            seen.add(m)
            want += deps.get(m, [])
    return sorted(seen)


def repack(deb, version, out):
    """The package again as 'version': the upgrade the upgrade case installs."""
    work = tempfile.mkdtemp(prefix="jakagw-repack-", dir=os.path.dirname(out))
    try:
        sh(["dpkg-deb", "-R", deb, work])
        control = os.path.join(work, "DEBIAN", "control")
        with open(control) as f:
            text = re.sub(r"^Version: .*$", "Version: " + version, f.read(), flags=re.M)
        with open(control, "w") as f:
            f.write(text)
        sh(["dpkg-deb", "--root-owner-group", "-b", work, out])
    finally:
        shutil.rmtree(work, True)


def previous_deb(outdir, deb):
    """The previous release's package (PREVIOUS), built once and kept."""
    deb_version = sh(["dpkg-deb", "-f", deb, "Version"]).strip()
    out = os.path.join(outdir, "previous-%s.deb" % PREVIOUS)
    if os.path.isfile(out):
        return out
    start = time.monotonic()
    os.makedirs(outdir, exist_ok=True)
    r = subprocess.run(["git", "-C", ROOT, "cat-file", "-e", PREVIOUS + "^{commit}"],
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit("make-service-image: the previous release, commit %s, is not in %s's "
                         "history (a shallow clone?): git fetch --unshallow" % (PREVIOUS, ROOT))
    work = tempfile.mkdtemp(prefix="previous.", dir=outdir)
    try:
        src = os.path.join(work, "src")
        os.makedirs(src)
        archive = subprocess.run(["git", "-C", ROOT, "archive", "--format=tar", PREVIOUS],
                                 capture_output=True, check=True).stdout
        subprocess.run(["tar", "-C", src, "-xf", "-"], input=archive, check=True)
        print("make-service-image: building the previous release's package (%s)" % PREVIOUS,
              file=sys.stderr)
        built = sh(["scripts/build-deb.sh", os.path.join(work, "deb")], cwd=src,
                   # Its own tree, not the checkout's git work tree around it.
                   env=dict(os.environ, DEB_BUILD_OPTIONS="nocheck", GIT_CEILING_DIRECTORIES=work),
                   timeout=1200).strip().splitlines()[-1]
        repack(built, "%s~%s" % (deb_version.split("+")[0], PREVIOUS), out + ".tmp")
        os.rename(out + ".tmp", out)
    finally:
        shutil.rmtree(work, True)
    print("make-service-image: %s in %.0f s" % (out, time.monotonic() - start), file=sys.stderr)
    return out


def build(outdir, deb):
    vmlinuz, initrd, version = kernel()
    previous = previous_deb(outdir, deb)
    key = image_key(deb, version)
    image = os.path.join(outdir, "image-%s.ext4" % key)
    if os.path.isfile(image):
        print("make-service-image: cached %s" % image, file=sys.stderr)
        return image
    start = time.monotonic()
    os.makedirs(outdir, exist_ok=True)
    for old in glob.glob(os.path.join(outdir, "image-*.ext4*")):
        os.remove(old)
    work = tempfile.mkdtemp(prefix="image.", dir=outdir)
    root = os.path.join(work, "root")
    try:
        deb_version = sh(["dpkg-deb", "-f", deb, "Version"]).strip()
        debs = os.path.join(work, "debs")
        os.makedirs(debs)
        shutil.copy(deb, debs)
        shutil.copy(previous, os.path.join(debs, "previous.deb"))
        newer = ["jakagw_%s+upgrade%d.deb" % (deb_version, n) for n in (1, 2)]
        for n, name in enumerate(newer, 1):
            repack(deb, "%s+upgrade%d" % (deb_version, n), os.path.join(debs, name))
        print("make-service-image: mmdebstrap (%s) with %s" % (", ".join(PACKAGES),
              os.path.basename(deb)), file=sys.stderr)
        sh(["mmdebstrap", "--mode=root", "--variant=apt", "--include=" + ",".join(PACKAGES)] +
           ["--dpkgopt=" + o for o in DPKG_OPTIONS] + [
            "--customize-hook=mkdir -p \"$1/root/debs\"",
            "--customize-hook=copy-in %s /root/debs" % " ".join(
                os.path.join(debs, name) for name in [os.path.basename(deb), "previous.deb"] +
                newer),
            "--customize-hook=chroot \"$1\" env DEBIAN_FRONTEND=noninteractive apt-get "
            "install -y --no-install-recommends /root/debs/%s" % os.path.basename(deb),
            # No package lists: the VM is offline, and apt reading them
            # under TCG took a minute of the upgrade case.
            "--customize-hook=chroot \"$1\" apt-get clean",
            "--customize-hook=rm -rf \"$1\"/var/lib/apt/lists/*",
            "bookworm", root] + apt_sources(), timeout=1200)
        for top in UNUSED_DIRS:
            for dirpath, dirnames, filenames in os.walk(os.path.join(root, top), topdown=False):
                for name in filenames:
                    path = os.path.join(dirpath, name)
                    if "jaka" not in path[len(root):] and name != "locale.alias":
                        os.remove(path)
                for name in dirnames:
                    path = os.path.join(dirpath, name)
                    if not os.path.islink(path) and not os.listdir(path):
                        os.rmdir(path)
        # This machine's kernel modules: the drivers the cases need.
        src = "/lib/modules/" + version
        for rel in module_closure(version):
            dest = os.path.join(root, "lib/modules", version, rel)
            os.makedirs(os.path.dirname(dest), exist_ok=True)
            shutil.copy2(os.path.join(src, rel), dest)
        for name in glob.glob(os.path.join(src, "modules.order")) + \
                glob.glob(os.path.join(src, "modules.builtin*")):
            shutil.copy2(name, os.path.join(root, "lib/modules", version))
        sh(["chroot", root, "depmod", version])
        # The agent, the robot, and the machine's basics.
        os.makedirs(os.path.join(root, "usr/local/lib/jakagw-test"))
        shutil.copy(AGENT, os.path.join(root, "usr/local/lib/jakagw-test/agent.py"))
        for name, text in (("vm-test-agent.service", AGENT_UNIT),
                           ("robot.service", ROBOT_UNIT)):
            with open(os.path.join(root, "etc/systemd/system", name), "w") as f:
                f.write(text)
        with open(os.path.join(root, "etc/fstab"), "w") as f:
            f.write("/dev/vda / ext4 rw,errors=remount-ro 0 1\n")
        with open(os.path.join(root, "etc/hostname"), "w") as f:
            f.write("jakagw-vm\n")
        sh(["chroot", root, "systemctl", "enable", "vm-test-agent.service",
            "robot.service"])
        # No login prompt on the console; no network to wait for.
        sh(["chroot", root, "systemctl", "mask", "serial-getty@ttyS0.service",
            "getty@tty1.service", "systemd-networkd-wait-online.service",
            "apt-daily.timer", "apt-daily-upgrade.timer", "e2scrub_reap.service"] + MASKED_UNITS)
        generators = os.path.join(root, "etc/systemd/system-generators")
        os.makedirs(generators)
        for name in MASKED_GENERATORS:
            check_generator = os.path.join(root, "lib/systemd/system-generators", name)
            if not os.path.exists(check_generator):
                raise SystemExit("make-service-image: no generator %s to mask" % name)
            os.symlink("/dev/null", os.path.join(generators, name))
        sh(["chroot", root, "passwd", "-d", "root"])
        # apt's debconf preconfiguration (a perl program, seconds under TCG
        # for each apt run of the upgrade case) asks nothing of jakagw,
        # which has no debconf questions: off, as its file invites.
        with open(os.path.join(root, "etc/apt/apt.conf.d/70debconf"), "w") as f:
            f.write("// Off in the service test VM (scripts/make-service-image.py): jakagw\n"
                    "// asks no debconf questions.\n")
        tmp = image + ".tmp"
        sh(["mke2fs", "-q", "-t", "ext4", "-L", "jakagw-vm", "-d", root, tmp,
            "%dM" % IMAGE_MB])
        os.rename(tmp, image)
    finally:
        # mmdebstrap unmounts what it mounted; never remove through a mount.
        with open("/proc/self/mounts") as f:
            mounted = [line.split()[1] for line in f if work in line.split()[1]]
        if mounted:
            print("make-service-image: not removing %s: mounted %s" % (work, mounted),
                  file=sys.stderr)
        else:
            shutil.rmtree(work, True)
    print("make-service-image: %s in %.0f s" % (image, time.monotonic() - start),
          file=sys.stderr)
    return image


def main():
    if len(sys.argv) != 3:
        raise SystemExit("usage: %s OUTDIR DEB" % sys.argv[0])
    print(build(os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])))


if __name__ == "__main__":
    main()
