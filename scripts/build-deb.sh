#!/bin/sh
# SPDX-License-Identifier: MIT
# Builds the Debian package with dpkg-buildpackage -us -uc -b, from a copy
# of the source files (in a git checkout: the files git knows or would add,
# as they are in the working tree), so that the build and its clean never
# touch this tree's build directories. Prints the path of the .deb.
#
#   scripts/build-deb.sh OUTDIR     the .deb lands in OUTDIR
set -eu
cd "$(dirname "$0")/.."
[ $# -eq 1 ] || { echo "usage: $0 OUTDIR" >&2; exit 2; }
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

arch=$(dpkg --print-architecture)
deb=$out/jakagw_${deb_version}_$arch.deb
rm -f "$deb"
log=$out/dpkg-buildpackage.log
echo "build-deb: dpkg-buildpackage -us -uc -b in $src (log: $log)" >&2
# A make that runs this script passes its variables (BUILD=..., PREFIX=...)
# down in the environment: the package's build starts from a clean one.
if ! (cd "$src" && env -i PATH="$PATH" HOME="${HOME:-/root}" LANG=C.UTF-8 \
        ${DEB_BUILD_OPTIONS:+DEB_BUILD_OPTIONS="$DEB_BUILD_OPTIONS"} \
        ${DEB_BUILD_PROFILES:+DEB_BUILD_PROFILES="$DEB_BUILD_PROFILES"} \
        dpkg-buildpackage -us -uc -b) >"$log" 2>&1; then
    tail -n 40 "$log" >&2
    echo "build-deb: dpkg-buildpackage failed; the whole log is $log" >&2
    exit 1
fi
[ -f "$deb" ] || { echo "build-deb: dpkg-buildpackage made no $deb" >&2; exit 1; }
echo "$deb"
