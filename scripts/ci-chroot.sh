#!/bin/bash
# SPDX-License-Identifier: MIT
# Runs a command in a root filesystem, as root, with /proc, /sys, /dev,
# /dev/pts and /dev/shm mounted, and exits with the command's status.
#
#   scripts/ci-chroot.sh ROOT COMMAND [ARG...]
#
# The mounts are made in a private mount namespace, so the host never sees
# them and they cannot outlive this script's namespace. On every exit path
# (success, failure, SIGINT, SIGTERM, SIGHUP) the processes still running in
# ROOT are stopped, the mounts are undone in reverse order, and the script
# checks that nothing is left mounted under ROOT. The environment inside is
# minimal: PATH, HOME, LANG, TERM and CI, and pip's settings (below).
set -euo pipefail

say() { echo "ci-chroot: $*"; }
[ $# -ge 2 ] || { echo "usage: $0 ROOT COMMAND [ARG...]" >&2; exit 2; }
[ "$(id -u)" -eq 0 ] || { echo "ci-chroot: must run as root" >&2; exit 2; }
ROOT=$(realpath "$1")
shift
[ "$ROOT" != / ] && [ -x "$ROOT/bin/sh" ] || { echo "ci-chroot: $ROOT is not a root filesystem" >&2; exit 2; }

# Same process, new mount namespace in which every mount is private.
if [ "${JAKAGW_CI_PRIVATE_NS:-}" != "$ROOT" ]; then
    export JAKAGW_CI_PRIVATE_NS=$ROOT
    exec unshare --mount --propagation private -- "$0" "$ROOT" "$@"
fi

MOUNTED=()
mnt() { # target mount-arguments...
    local target=$ROOT$1
    shift
    mount "$@" "$target"
    MOUNTED+=("$target")
}

# Processes whose root directory is ROOT: what the command left running.
in_root() {
    local p r
    for p in /proc/[0-9]*; do
        r=$(readlink "$p/root" 2>/dev/null) || continue
        [ "$r" = "$ROOT" ] && echo "${p#/proc/}"
    done
    return 0
}

cleanup() {
    local status=$? pids= i target left
    set +e
    trap '' INT TERM HUP PIPE
    # Again and again, to catch what was forked meanwhile; SIGKILL after 5 s.
    for i in $(seq 1 20); do
        pids=$(in_root)
        [ -z "$pids" ] && break
        [ "$i" -eq 1 ] && say "stopping what still runs in $ROOT:" $pids
        kill -"$([ "$i" -le 10 ] && echo TERM || echo KILL)" $pids 2>/dev/null || true
        sleep 0.5
    done
    [ -z "$pids" ] || say "could not stop:" $pids
    for ((i = ${#MOUNTED[@]} - 1; i >= 0; i--)); do
        target=${MOUNTED[i]}
        umount "$target" 2>/dev/null || { sleep 1; umount "$target"; } ||
            { say "umount $target failed; detaching it"; umount -l "$target" || true; }
    done
    left=$(findmnt -rn -o TARGET | grep -F "$ROOT/" || true)
    if [ -n "$left" ]; then
        say "still mounted under $ROOT:" $left
        [ "$status" -eq 0 ] && status=1
    else
        say "unmounted ${#MOUNTED[@]} file systems; nothing left mounted under $ROOT"
    fi
    exit "$status"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
trap 'exit 129' HUP

mnt /proc -t proc -o nosuid,nodev,noexec proc
mnt /sys -t sysfs -o ro,nosuid,nodev,noexec sysfs
mnt /dev --bind /dev
mnt /dev/pts --bind /dev/pts
mnt /dev/shm -t tmpfs -o nosuid,nodev,mode=1777 shm
if [ -f /etc/resolv.conf ]; then   # for apt-get
    rm -f "$ROOT/etc/resolv.conf"
    cp -L /etc/resolv.conf "$ROOT/etc/resolv.conf"
fi

# The machine's way to the Python package index, if it has one of its own
# (a certificate authority for pip, a local folder of wheels): the tests
# that install from PyPI reach it from inside as they do outside. Nothing
# else of the host's environment goes in.
PIP_ENV=()
if [ -n "${PIP_CERT:-}" ] && [ -r "$PIP_CERT" ]; then
    mkdir -p "$ROOT/etc/jakagw-ci"
    cp -L "$PIP_CERT" "$ROOT/etc/jakagw-ci/pip-ca.pem"
    PIP_ENV+=(PIP_CERT=/etc/jakagw-ci/pip-ca.pem)
fi
if [ -n "${PIP_FIND_LINKS:-}" ] && [ -d "$PIP_FIND_LINKS" ]; then
    mkdir -p "$ROOT$PIP_FIND_LINKS"
    mnt "$PIP_FIND_LINKS" --bind -o ro "$PIP_FIND_LINKS"
    PIP_ENV+=(PIP_FIND_LINKS="$PIP_FIND_LINKS")
fi
[ -n "${PIP_DEFAULT_TIMEOUT:-}" ] && PIP_ENV+=(PIP_DEFAULT_TIMEOUT="$PIP_DEFAULT_TIMEOUT")

# In the background so that a signal interrupts the wait at once.
chroot "$ROOT" /usr/bin/env -i \
    PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    HOME=/root LANG=C.UTF-8 TERM=dumb CI="${CI:-}" "${PIP_ENV[@]}" "$@" </dev/null &
wait $!
