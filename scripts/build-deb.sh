#!/bin/sh
# SPDX-License-Identifier: MIT
# Builds the Debian package with dpkg-buildpackage -us -uc -b, from a copy
# of the source files (in a git checkout: the files git knows or would add,
# as they are in the working tree), so that the build and its clean never
# touch this tree's build directories. Prints the path of the .deb.
#
#   scripts/build-deb.sh OUTDIR                 the .deb lands in OUTDIR
#   scripts/build-deb.sh OUTDIR ARCH SYSROOT    for an ARM board (make deb
#                                               ARCH=arm64|armhf)
#
# For ARCH, the package is cross-built (dpkg-buildpackage -a ARCH) by the
# Makefile's ARCH= build against SYSROOT, which scripts/make-sysroot.sh
# makes if needed: the build dependencies are there, not in this machine's
# package database, so dpkg-buildpackage does not look for them (-d).
# dpkg-shlibdeps computes Depends from the symbols and shlibs files of the
# sysroot's packages (debian/rules).
set -eu
cd "$(dirname "$0")/.."
[ $# -eq 1 ] || [ $# -eq 3 ] || { echo "usage: $0 OUTDIR [ARCH SYSROOT]" >&2; exit 2; }
host_arch=${2:-}
sysroot=${3:-}
cross_cc=
if [ -n "$host_arch" ]; then
    scripts/make-sysroot.sh "$host_arch" "$sysroot"
    sysroot=$(cd "$sysroot" && pwd)
    cross_cc=$(dpkg-architecture -a"$host_arch" -qDEB_HOST_GNU_TYPE 2>/dev/null)-gcc
    # Its tests run under qemu-user in make test ARCH=..., not in the
    # package build.
    DEB_BUILD_OPTIONS=$(echo "${DEB_BUILD_OPTIONS:-} nocheck" | sed 's/^ //')
fi
for tool in dpkg-buildpackage dh; do
    command -v $tool >/dev/null 2>&1 ||
        { echo "build-deb: no $tool: run 'make deps DEPS_GROUPS=package' (or scripts/install-deps.sh package)" >&2; exit 1; }
done

version=$(sed -n 's/^VERSION *:= *//p' Makefile)
deb_version=$(dpkg-parsechangelog -S Version)
case $deb_version in
    "$version"|"$version"-*|"$version"+*) ;;
    *) echo "build-deb: debian/changelog says $deb_version, the Makefile $version" >&2; exit 1 ;;
esac

out=$(mkdir -p "$1" && cd "$1" && pwd)
src=$out/jakagw-$version
rm -rf "$src"
mkdir -p "$src"
if git rev-parse --is-inside-work-tree >/dev/null 2>&1; then
    # Deleted files that git still lists are skipped.
    git ls-files -z --cached --others --exclude-standard |
        xargs -0 sh -c 'for f; do [ -e "$f" ] && printf "%s\0" "$f"; done' sh |
        xargs -0 cp --parents -t "$src"
else
    tar -C . --exclude='./build*' --exclude=./.git -cf - . | tar -C "$src" -xf -
fi

arch=${host_arch:-$(dpkg --print-architecture)}
deb=$out/jakagw_${deb_version}_$arch.deb
rm -f "$deb"
log=$out/dpkg-buildpackage.log
echo "build-deb: dpkg-buildpackage -us -uc -b in $src (log: $log)" >&2
# A make that runs this script passes its variables (BUILD=..., PREFIX=...)
# down in the environment: the package's build starts from a clean one.
if ! (cd "$src" && env -i PATH="$PATH" HOME="${HOME:-/root}" LANG=C.UTF-8 \
        ${DEB_BUILD_OPTIONS:+DEB_BUILD_OPTIONS="$DEB_BUILD_OPTIONS"} \
        ${DEB_BUILD_PROFILES:+DEB_BUILD_PROFILES="$DEB_BUILD_PROFILES"} \
        ${host_arch:+JAKAGW_SYSROOT="$sysroot" CC="$cross_cc"} \
        dpkg-buildpackage -us -uc -b ${host_arch:+-a "$host_arch" -d -Pcross,nocheck}) >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "build-deb: dpkg-buildpackage failed; the whole log is $log" >&2
    exit 1
fi
[ -f "$deb" ] || { echo "build-deb: dpkg-buildpackage made no $deb" >&2; exit 1; }
echo "$deb"
