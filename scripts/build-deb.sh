#!/usr/bin/env bash
# build-deb.sh: builds the Debian packages librsmodbus5 (libmodbus.so.5; provides,
# conflicts with and replaces libmodbus5), librsmodbus-dev (headers, libmodbus.so,
# libmodbus.a, libmodbus.pc, manual pages, examples; provides libmodbus-dev) and
# rsmodbus-gateway (the gateway, its manual page, systemd unit template and example
# configuration) with `dpkg-buildpackage -b` and debian/, using the cargo on PATH
# (Rust >= 1.85).
#
# Usage: scripts/build-deb.sh [OUTDIR]     (default target/debian)
# Needs: debhelper, dpkg-dev, gcc, pkg-config, python3 (scripts/install-deps.sh).
# Install the result with: apt install ./target/debian/librsmodbus5_*.deb ./target/debian/librsmodbus-dev_*.deb
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
out=$(realpath -m "${1:-target/debian}")

command -v cargo >/dev/null || export PATH="$HOME/.cargo/bin:$PATH"
for tool in cargo dpkg-buildpackage dh python3 gcc; do
    command -v "$tool" >/dev/null || {
        echo "build-deb.sh: $tool not found (run scripts/install-deps.sh; cargo comes from rustup)" >&2
        exit 1
    }
done

rm -rf "$out"
mkdir -p "$out"
version=$(dpkg-parsechangelog -SVersion)
arch=$(dpkg-architecture -qDEB_HOST_ARCH)
# --post-clean: `debian/rules clean` after the build (dh_clean removes debian/PACKAGE/,
# debian/tmp/ and debhelper's files); after a failed build too, here: the tree is left
# as it was (c-tests/suites/package.sh checks).
if ! DEB_OUT_DIR=$out dpkg-buildpackage -b -us -uc --post-clean \
    --buildinfo-option="-u$out" --buildinfo-file="$out/rsmodbus_${version}_${arch}.buildinfo" \
    --changes-option="-u$out" --changes-file="$out/rsmodbus_${version}_${arch}.changes"; then
    debian/rules clean >/dev/null 2>&1 || true
    echo "build-deb.sh: dpkg-buildpackage failed" >&2
    exit 1
fi
echo
echo "packages in ${out#"$PWD"/}:"
for deb in "$out"/*.deb; do
    printf '  %-40s %8s bytes\n' "$(basename "$deb")" "$(stat -c %s "$deb")"
done
