#!/bin/sh
# Installs the Debian 12 packages jakagw needs to build, run and test, if any
# is missing. Runs apt-get as root, or through sudo.
set -eu

PACKAGES="build-essential pkg-config libuv1-dev libmodbus-dev libcjson-dev
libinih-dev libsystemd-dev libcmocka-dev mbpoll python3 python3-pymodbus valgrind
systemd"

missing=""
for p in $PACKAGES; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
        missing="$missing $p"
    fi
done
[ -z "$missing" ] && exit 0

echo "install-deps: installing:$missing"
if [ "$(id -u)" -eq 0 ]; then
    SUDO=""
elif command -v sudo >/dev/null 2>&1; then
    SUDO="sudo"
else
    echo "install-deps: missing packages:$missing; run as root or install sudo" >&2
    exit 1
fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
# shellcheck disable=SC2086
$SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
