#!/usr/bin/env bash
# Installs the Debian packages the tests need (Debian 12, as root). Debian's own
# libmodbus is the oracle of the differential tests; mbpoll is an unmodified
# consumer of libmodbus5; debhelper and dpkg-dev build the .deb packages
# (scripts/build-deb.sh). python3-venv holds the interoperability tests' pinned pymodbus
# (c-tests/suites/interop.sh, from PyPI). abigail-tools (abidw, abidiff) compares the
# ABI with its baseline (c-tests/suites/abi-check.sh, scripts/abi-update.sh). openssl
# makes the TLS certificates (c-tests/tls/make-certs.sh: the TLS tests, also in
# `cargo test`, the benchmark, the profile-guided build's training) and is the TLS
# tests' other peer (s_client, s_server). cmake builds mbusd beside our gateway
# (c-tests/suites/gateway.sh, when ../shared/anchors/mbusd is there). Every suite finds
# what it needs here, so that none runs apt-get beside another (c-tests/run runs some
# side by side). At the end: llvm-profdata for scripts/build-pgo.sh.
set -euo pipefail
packages=(gcc g++ make pkg-config binutils libmodbus-dev libmodbus5 socat mbpoll valgrind man-db openssl
    python3 debhelper dpkg-dev python3-venv abigail-tools cmake)
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

# llvm-profdata of rustc's own LLVM, for the profile-guided build (scripts/build-pgo.sh:
# the Debian packages and the benchmark), when build-pgo.sh finds none: rustup's
# llvm-tools component, else Debian's llvm-N when it has rustc's version N.
if command -v rustc >/dev/null; then
    if ! "$(dirname "$0")/build-pgo.sh" --find-profdata >/dev/null 2>&1; then
        llvm_major=$(rustc -vV | sed -n 's/^LLVM version: \([0-9]*\).*/\1/p')
        echo "installing: llvm-profdata (LLVM $llvm_major)"
        { command -v rustup >/dev/null && rustup component add llvm-tools >/dev/null 2>&1; } \
            || apt-get install -y -qq --no-install-recommends "llvm-$llvm_major" >/dev/null \
            || echo "install-deps.sh: no llvm-profdata for LLVM $llvm_major (scripts/build-pgo.sh needs it)" >&2
    fi
fi
