#!/bin/bash
# SPDX-License-Identifier: MIT
# Builds matiec (the IEC 61131-3 compiler of the Beremiz project) from its
# source tarball, once per tarball, and prints the directory of the build
# (iec2c in it, the runtime headers in its lib/C/).
#
#   tests/plc/matiec.sh BUILD_DIR
#
# The tarball is outside this repository (MATIEC_TARBALL, default
# ../shared/tools/matiec/matiec-*.tar.gz from the repository's root): matiec
# is a test tool (GPL-3.0, its runtime headers LGPL), never shipped or
# copied into the project. The build goes to BUILD_DIR/matiec-HASH (or
# MATIEC_CACHE/matiec-HASH: CI keeps it across runs there), HASH the
# tarball's SHA-256, and is reused while that directory holds iec2c.
#
# Exit status: 0 built (or cached); 1 the build failed; 77 no tarball (the
# caller decides: make test-plc fails under CI=true, skips otherwise).
set -euo pipefail
cd "$(dirname "$0")/../.."

[ $# -eq 1 ] || { echo "usage: $0 BUILD_DIR" >&2; exit 2; }
build=$1
tarball=${MATIEC_TARBALL:-}
if [ -z "$tarball" ]; then
    tarball=$(ls ../shared/tools/matiec/matiec-*.tar.gz 2>/dev/null | head -n 1 || true)
    [ -n "$tarball" ] || tarball=../shared/tools/matiec/matiec-*.tar.gz
fi
if [ ! -f "$tarball" ]; then
    echo "matiec: no source tarball at $tarball (set MATIEC_TARBALL)" >&2
    exit 77
fi

hash=$(sha256sum "$tarball" | cut -c1-12)
dir=$(realpath -m "${MATIEC_CACHE:-$build}/matiec-$hash")
if [ -x "$dir/iec2c" ] && [ -f "$dir/lib/C/iec_std_lib.h" ]; then
    echo "$dir"
    exit 0
fi

rm -rf "$dir" "$dir.tmp" "$dir.keep"
mkdir -p "$dir.tmp"
start=$(date +%s)
log=$(realpath -m "$build")/matiec-build.log
mkdir -p "$(dirname "$log")"
tar -C "$dir.tmp" --strip-components=1 -xzf "$tarball"
if ! (cd "$dir.tmp" && autoreconf -i && ./configure && make -j2) >"$log" 2>&1; then
    tail -n 30 "$log" >&2
    echo "matiec: the build failed (log: $log)" >&2
    exit 1
fi
# Only what the tests use stays: the compiler, its libraries (lib/, the
# standard function blocks and the C runtime headers) and the licences.
mkdir -p "$dir.keep"
mv "$dir.tmp/iec2c" "$dir.tmp/lib" "$dir.tmp/COPYING" "$dir.keep/"
rm -rf "$dir.tmp"
mv "$dir.keep" "$dir"
echo "matiec: built $(basename "$tarball") in $(($(date +%s) - start)) s into $dir" >&2
echo "$dir"
