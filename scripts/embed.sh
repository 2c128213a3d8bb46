#!/bin/sh
# SPDX-License-Identifier: MIT
# Writes FILE as a C array named NAME (NUL-terminated, NAME_size without
# the NUL), so the status page is part of the binary: scripts/embed.sh NAME FILE
set -eu
name=$1
file=$2
echo "/* SPDX-License-Identifier: MIT */"
echo "/* Generated from $file by scripts/embed.sh: do not edit. */"
echo "#include <stddef.h>"
echo "extern const char ${name}[];"
echo "extern const size_t ${name}_size;"
echo "const char ${name}[] = {"
od -An -v -tx1 "$file" | sed 's/  */ /g; s/^ //; s/ $//; /^$/d; s/\([0-9a-f][0-9a-f]\)/0x\1,/g'
echo "0x00};"
echo "const size_t ${name}_size = sizeof(${name}) - 1;"
