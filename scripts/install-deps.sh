#!/usr/bin/env bash
# Installs the Debian packages the tests need (Debian 12, as root). Debian's own
# libmodbus is the oracle of the differential tests; mbpoll is an unmodified
# consumer of libmodbus5; debhelper and dpkg-dev build the .deb packages
# (scripts/build-deb.sh). python3-venv holds the interoperability tests' pinned pymodbus
# (scripts/run-interop-tests.sh, from PyPI).
set -euo pipefail
packages=(gcc g++ make pkg-config binutils libmodbus-dev libmodbus5 socat mbpoll valgrind man-db
    python3 debhelper dpkg-dev python3-venv)
missing=()
for p in "${packages[@]}"; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q 'install ok installed' || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    echo "installing: ${missing[*]}"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi
