#!/bin/sh
# SPDX-License-Identifier: MIT
# Installs the Debian 12 packages jakagw needs, if any is missing, and says
# which and why. Runs apt-get as root, or through sudo.
#
#   scripts/install-deps.sh             the default groups (what make deps,
#                                       make demo and make test need)
#   scripts/install-deps.sh GROUP...    those groups only
#   scripts/install-deps.sh --list      the groups, their reasons and packages
#
# Every program and Python module the build and the tests use comes from a
# package named here, never from a Recommends: packages are installed with
# --no-install-recommends, as on a minimal machine.
#
# To add a group: one group() line below, with a name, a one-line reason and
# the packages; add the name to DEFAULT_GROUPS if make deps should install it.
set -eu

GROUPS_ALL=""
group() { # name reason package...
    name=$1 reason=$2
    shift 2
    GROUPS_ALL="$GROUPS_ALL $name"
    eval "REASON_$name=\$reason PKGS_$name=\"\$*\""
}

group build "to compile jakagw and jakasim: compiler, make, pkg-config, library headers (libssl-dev: OpenSSL 3 for Modbus/TCP Security and TLS to the robot; libmicrohttpd-dev: the HTTP server of /metrics and the status page)" \
    build-essential pkg-config \
    libuv1-dev libmodbus-dev libcjson-dev libinih-dev libsystemd-dev libssl-dev libmicrohttpd-dev
group tests "to run the tests: cmocka; python3 with pymodbus and serial_asyncio (pymodbus 3.0.0 imports it); mbpoll; socat (the RTU tests join two ptys with it); systemd-analyze; valgrind (make valgrind); the openssl command (the TLS tests make their certificates with it and connect with s_client)" \
    libcmocka-dev \
    python3 python3-pymodbus python3-serial-asyncio \
    mbpoll socat systemd valgrind openssl
group can "to test the CAN mirror on a real kernel CAN stack, and netem on single links, in a VM: qemu, Debian's kernel and its can/vcan/netem modules, busybox, candump and cansend, iproute2's tc, a venv for cantools" \
    qemu-system-x86 linux-image-amd64 busybox-static can-utils iproute2 python3-venv
group package "to build the Debian package and test it and the units (make deb, make test-package): debhelper, dpkg-dev, lintian, mmdebstrap for a fresh root filesystem to install it in, man-db and groff-base to check the man pages, procps for the kill the units' ExecReload runs (systemd-analyze verify looks for it)" \
    debhelper dpkg-dev lintian mmdebstrap man-db groff-base procps
group service "to test the installed package under systemd in a VM (make test-service, tests/service): mmdebstrap for the Debian 12 image, mke2fs (e2fsprogs) to make it a disk without a loop device, qemu and Debian's kernel with its stock initrd to boot it, mbpoll as the RTU master on this machine's end of the VM's serial ports" \
    mmdebstrap e2fsprogs qemu-system-x86 linux-image-amd64 mbpoll
group cross "to build, package and test for ARM boards (make ARCH=arm64|armhf): Debian's cross compilers, and qemu-user to run their binaries (the sysroot comes from mmdebstrap, group package)" \
    gcc-aarch64-linux-gnu gcc-arm-linux-gnueabihf qemu-user
group netfault "to inject network faults in the fault-injection suite (test_faults.py): nftables (silent pulls, resets, random loss), iproute2 (ip, ss) in a namespace made with unshare (util-linux, always installed)" \
    nftables iproute2

group plc "to build matiec, the IEC 61131-3 compiler the PLC library's tests compile its Structured Text with (make test-plc, from its source tarball in ../shared/tools/matiec): flex and bison generate its parser, autoconf and automake its build (autoreconf), g++ compiles it (build-essential, group build)" \
    flex bison autoconf automake

group web "to test /metrics, the alert rules (promtool, and the prometheus server end to end: tests/integration/test_alerts.py) and the status page (tests/integration/test_http.py, make screenshot): promtool from prometheus, headless chromium driven by python3-selenium through chromium-driver" \
    prometheus chromium chromium-driver python3-selenium

group fuzz "to run the libFuzzer targets (make fuzz, make fuzz-ci): clang, and the libFuzzer and sanitizer runtimes it links, which Debian 12 ships apart in libclang-rt-14-dev" \
    clang libclang-rt-14-dev

group prove "to prove the Modbus request check and the RTU CRC and length functions (make prove): Frama-C's WP (frama-c-base), why3 between it and the solvers, the z3 and cvc4 solvers (alt-ergo, WP's usual one, is not packaged for Debian 12)" \
    frama-c-base why3 z3 cvc4

DEFAULT_GROUPS="build tests web can package service cross netfault plc prove"
# CI's make test also runs the fuzz targets (make fuzz-ci). The proofs'
# packages (223 MB, 960 MB installed) are not its: .ci/run installs them
# and runs make prove beside the ARM runs, where they cost no wall time.
[ "${CI:-}" = true ] && DEFAULT_GROUPS="${DEFAULT_GROUPS% prove} fuzz"

say() { echo "install-deps: $*"; }
fail() { echo "install-deps: $*" >&2; exit 1; }

installed() {
    dpkg-query -W -f='${Status}' "$1" 2>/dev/null | grep -q "install ok installed"
}

if [ "${1:-}" = --list ]; then
    for g in $GROUPS_ALL; do
        eval "echo \"$g: \$REASON_$g\"; echo \"    \$PKGS_$g\""
    done
    exit 0
fi

wanted=${*:-$DEFAULT_GROUPS}
missing=""
for g in $wanted; do
    case " $GROUPS_ALL " in
        *" $g "*) ;;
        *) fail "unknown group '$g' (groups:$GROUPS_ALL)" ;;
    esac
    eval "reason=\$REASON_$g pkgs=\$PKGS_$g"
    absent=""
    for p in $pkgs; do
        installed "$p" || absent="$absent $p"
    done
    missing="$missing$absent"
    if [ -z "$absent" ]; then
        say "$g ($reason): $pkgs - all installed"
    else
        say "$g ($reason): $pkgs - installing:$absent"
    fi
done
[ -z "$missing" ] && exit 0

if [ "$(id -u)" -eq 0 ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
else
    fail "cannot install$missing: run as root, or install sudo"
fi
command -v apt-get >/dev/null 2>&1 || fail "cannot install$missing: no apt-get (this needs Debian 12)"

count=$(echo $missing | wc -w)
start=$(date +%s)
log=$(mktemp)
trap 'rm -f "$log"' EXIT
export DEBIAN_FRONTEND=noninteractive
if ! $SUDO apt-get update -qq >"$log" 2>&1; then
    tail -n 30 "$log" >&2
    fail "apt-get update failed: $(grep '^E:' "$log" | head -1)"
fi
for p in $missing; do
    apt-cache show --no-all-versions "$p" >/dev/null 2>&1 ||
        fail "cannot install $p: no such package in the apt sources"
done
# shellcheck disable=SC2086
if ! $SUDO apt-get install -y -q --no-install-recommends $missing >"$log" 2>&1; then
    tail -n 30 "$log" >&2
    fail "apt-get install failed: $(grep '^E:' "$log" | head -1)"
fi
for p in $missing; do
    installed "$p" || fail "cannot install $p: apt-get did not install it"
done
say "installed $count packages, $(grep -c '^Setting up ' "$log" || true) with their dependencies, in $(($(date +%s) - start)) s"
