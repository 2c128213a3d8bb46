#!/bin/sh
# SPDX-License-Identifier: MIT
# Makes the sysroot a cross build for an ARM board compiles and links
# against, and that qemu-user runs the binaries in: Debian 12's own packages
# for that architecture, extracted with mmdebstrap --variant=extract (no
# package is configured, nothing runs, the host's package database and its
# architectures are never touched).
#
#   scripts/make-sysroot.sh ARCH DIR     ARCH is arm64 or armhf
#
# The packages are the library headers (lib*-dev) of install-deps.sh's
# groups 'build' and 'tests' (so a library added there reaches the sysroot
# too), and libc6-dev; their run-time libraries come as dependencies.
# DIR is kept while the architecture, the package list and the apt sources
# are the same (DIR/.jakagw-sysroot records them); otherwise it is made
# again. Prints nothing when DIR is up to date.
#
# DIR/DEBIAN/symbols and DIR/DEBIAN/shlibs are the symbols and shlibs files
# of every package extracted, as Debian ships them: dpkg-shlibdeps -S DIR
# takes them, as for a package being built, and computes a binary's
# Depends from them (debian/rules, cross builds).
#
# Environment: SYSROOT_APT_SOURCES names the apt sources file (default:
# this machine's Debian entries, as .ci/run takes them).
set -eu
cd "$(dirname "$0")/.."
say() { echo "make-sysroot: $*" >&2; }
fail() { say "$*"; exit 1; }
[ $# -eq 2 ] || { echo "usage: $0 arm64|armhf DIR" >&2; exit 2; }
arch=$1
dir=$2
case $arch in
    arm64|armhf) ;;
    *) fail "unknown architecture '$arch' (arm64 or armhf)" ;;
esac

# This machine's Debian sources: debian.sources, or the deb822 file
# mmdebstrap writes into a root it makes (0000debian.sources: CI's), or
# sources.list.
sources=${SYSROOT_APT_SOURCES:-}
if [ -z "$sources" ]; then
    for f in /etc/apt/sources.list.d/debian.sources /etc/apt/sources.list.d/*debian*.sources \
             /etc/apt/sources.list; do
        if [ -s "$f" ] && grep -q 'debian' "$f"; then
            sources=$f
            break
        fi
    done
fi

packages=$(scripts/install-deps.sh --list |
           awk '/^[a-z]+:/ { g = $1 } g == "build:" || g == "tests:" { print }' |
           tr ' ' '\n' | grep -E '^lib.*-dev$' | sort -u | tr '\n' ' ')
packages="libc6-dev $packages"
[ "$packages" != "libc6-dev " ] || fail "no library packages in scripts/install-deps.sh --list"

# The layout line changes when this script changes what it makes.
want="layout 4
arch $arch
packages $packages
sources $( { [ -n "$sources" ] && cat "$sources"; } | sha256sum | cut -c1-16)"
stamp=$dir/.jakagw-sysroot
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    exit 0
fi

command -v mmdebstrap >/dev/null 2>&1 ||
    fail "no mmdebstrap: run 'make deps' (or scripts/install-deps.sh package)"
start=$(date +%s)
say "making the $arch sysroot $dir: mmdebstrap --variant=extract" \
    "--architectures=$arch bookworm, with $packages(apt sources: ${sources:-the default mirror})"
tmp=$dir.tmp.$$
trap 'rm -rf "$tmp"' EXIT
rm -rf "$tmp"
mkdir -p "$(dirname "$dir")"
log=$(dirname "$dir")/make-sysroot.log
extract() { # sources-file
    rm -rf "$tmp"
    mmdebstrap --variant=extract --architectures="$arch" --skip=cleanup/apt/cache \
        --include="$(echo $packages | tr ' ' ',')" bookworm "$tmp" ${1:+"$1"} >"$log" 2>&1
}
# A mirror's security index for a foreign architecture can lag behind
# amd64's (apt: "File has unexpected size ... Mirror sync in progress?").
# Then the sysroot is made from the other suites (bookworm and its point
# releases), which carry the same libraries and ABI: good enough to compile,
# link and compute Depends against, and to test under emulation.
without_security=
if ! extract "$sources"; then
    if grep -q -- '-security.*\(unexpected size\|Hash Sum mismatch\)' "$log"; then
        if [ -z "$sources" ]; then
            # mmdebstrap's own default: deb.debian.org, with security.
            sources=$dir.$$.default.sources
            printf 'Types: deb\nURIs: http://deb.debian.org/debian\nSuites: bookworm bookworm-updates\nComponents: main\n\nTypes: deb\nURIs: http://security.debian.org/debian-security\nSuites: bookworm-security\nComponents: main\n' >"$sources"
        fi
        say "the mirror's bookworm-security index for $arch is inconsistent:" \
            "$(grep -m1 -o 'File has unexpected size[^.]*' "$log" || echo 'hash mismatch');" \
            "making the sysroot from the other suites of $sources"
        # mmdebstrap and apt tell the two formats apart by the name.
        without_security=$dir.$$.${sources##*.}
        if [ "${sources%.sources}" != "$sources" ]; then   # deb822: drop the stanza
            awk 'BEGIN { RS = ""; ORS = "\n\n" } !/Suites:[^\n]*-security/' "$sources"
        else
            grep -v -- '-security' "$sources"
        fi >"$without_security"
        ok=0
        extract "$without_security" && ok=1
        rm -f "$without_security" "$dir.$$.default.sources"
        [ "$ok" = 1 ] || { tail -n 20 "$log" >&2; fail "mmdebstrap failed; the whole log is $log"; }
    else
        tail -n 20 "$log" >&2
        fail "mmdebstrap failed; the whole log is $log"
    fi
fi

# qemu-user -L looks up every path the binary opens in the sysroot first:
# /dev and /tmp must be the machine's own.
rm -rf "$tmp/dev" "$tmp/tmp"

# Absolute symbolic links (libm.so -> /lib/TRIPLET/libm.so.6) would point
# into this machine, where nothing is found, and the linker would take
# libm.a instead: each is made relative, inside the sysroot.
find "$tmp" -type l -lname '/*' | while read -r link; do
    ln -sfnr "$tmp$(readlink "$link")" "$link"
done
dangling=$(find "$tmp" -xtype l -lname '/*' | head -n 3)
[ -z "$dangling" ] || fail "absolute symbolic links left in $tmp: $dangling"

# The packages' symbols and shlibs files, for dpkg-shlibdeps; a list of
# what the sysroot holds, with versions. The .deb files are not kept.
mkdir -p "$tmp/DEBIAN"
: >"$tmp/DEBIAN/symbols"
: >"$tmp/DEBIAN/shlibs"
: >"$tmp/.jakagw-packages"
for deb in "$tmp"/var/cache/apt/archives/*.deb; do
    ctrl=$(mktemp -d)
    dpkg-deb --control "$deb" "$ctrl"
    for f in symbols shlibs; do
        [ -f "$ctrl/$f" ] && cat "$ctrl/$f" >>"$tmp/DEBIAN/$f"
    done
    rm -rf "$ctrl"
    dpkg-deb --show --showformat='${Package} ${Version}\n' "$deb" >>"$tmp/.jakagw-packages"
done
count=$(wc -l <"$tmp/.jakagw-packages")
[ "$count" -gt 0 ] || fail "mmdebstrap left no .deb in $tmp/var/cache/apt/archives"
rm -rf "$tmp"/var/cache/apt/archives
[ -e "$tmp/usr/lib/$( [ "$arch" = arm64 ] && echo aarch64-linux-gnu || echo arm-linux-gnueabihf)/libuv.so" ] ||
    fail "the sysroot has no libuv.so: $log"
echo "$want" >"$tmp/.jakagw-sysroot"
suites="bookworm, bookworm-updates, bookworm-security"
[ -n "$without_security" ] && suites="bookworm, bookworm-updates (the security index was inconsistent)"
echo "$suites" >"$tmp/.jakagw-suites"

rm -rf "$dir"
mv "$tmp" "$dir"
trap - EXIT
say "$dir: $count packages from $suites, $(du -sm "$dir" | cut -f1) MB, in $(($(date +%s) - start)) s"
