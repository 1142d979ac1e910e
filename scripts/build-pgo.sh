#!/usr/bin/env bash
# build-pgo.sh: builds the release library with profile-guided optimisation (PGO), the
# build the Debian packages ship and the benchmark measures. Three steps:
#   1. a release library instrumented for profiling (DIR/gen);
#   2. a training run: benches/pgo-train.py runs the benchmark's server and client,
#      both loading that library, through every benchmark case over TCP loopback and
#      two (read 125 registers, read 1 register) over TLS (a fixed number of
#      transactions; the TLS profile's counts rounded to a multiple of it, which
#      leaves out its handshakes' varying few: the same source gives the same profile,
#      and the same library);
#   3. the release library again, optimised with the merged profile
#      (DIR/rsmodbus-HASH.profdata): DIR/release/libmodbus.so, .so.5, .a, libmodbus.pc.
# Why: measured with benches/ab.py, the optimised library is about 1.5% faster
# over TCP than `cargo build --release` (benches/README.md), with no code of its own.
#
# A library built from the same committed sources, toolchain and flags is kept (see
# "What the build reads" below).
# Usage: scripts/build-pgo.sh [--debian-flags] [DIR]      (default target/pgo)
#          --debian-flags: with the flags dh gives debian/rules (dpkg-buildflags: the
#          hardening of the C code inside, ring's; SOURCE_DATE_EPOCH from
#          debian/changelog): the library the packages ship, which their build then
#          keeps (the test run builds it so)
#        scripts/build-pgo.sh --find-profdata   (prints the llvm-profdata it would use;
#                                               exit 1 without one: install-deps.sh)
# Needs: llvm-profdata of the LLVM that rustc was built with ($LLVM_PROFDATA, rustup's
# llvm-tools component, or Debian's llvm-N), gcc, python3 and openssl (the TLS
# training's certificates, c-tests/tls/make-certs.sh); with --debian-flags, dpkg-dev.
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."

die() { echo "build-pgo.sh: $*" >&2; exit 1; }
command -v cargo >/dev/null || export PATH="$HOME/.cargo/bin:$PATH"
command -v rustc >/dev/null || die "rustc not found (rustup installs it)"

# A profile is read only by the LLVM major version that wrote its format.
llvm_major=$(rustc -vV | sed -n 's/^LLVM version: \([0-9]*\).*/\1/p')
host=$(rustc -vV | sed -n 's/^host: //p')
[ -n "$llvm_major" ] || die "cannot tell rustc's LLVM version (rustc -vV)"
profdata=${LLVM_PROFDATA:-}
if [ -z "$profdata" ]; then
    for candidate in "$(rustc --print sysroot)/lib/rustlib/$host/bin/llvm-profdata" \
        "$(command -v "llvm-profdata-$llvm_major" || true)"; do
        if [ -n "$candidate" ] && [ -x "$candidate" ]; then profdata=$candidate; break; fi
    done
fi
[ -n "$profdata" ] || die "no llvm-profdata for LLVM $llvm_major: rustup component add llvm-tools, \
or apt-get install llvm-$llvm_major, or set LLVM_PROFDATA"
profdata_major=$("$profdata" --version | sed -n 's/.*LLVM version \([0-9]*\).*/\1/p')
[ "$profdata_major" = "$llvm_major" ] || die "$profdata is LLVM $profdata_major, rustc's is LLVM $llvm_major"
if [ "${1:-}" = --find-profdata ]; then
    echo "$profdata"
    exit 0
fi

if [ "${1:-}" = --debian-flags ]; then
    shift
    . scripts/deb-build-env.sh
    deb_build_env || die "dpkg-buildflags or dpkg-parsechangelog failed (dpkg-dev)"
fi
out=$(realpath -m "${1:-target/pgo}")
for tool in cargo gcc python3 openssl; do
    command -v "$tool" >/dev/null || die "$tool not found (scripts/install-deps.sh installs it)"
done

# What the build reads: the tracked files (by their blob hashes; c-tests/common holds
# the training programs' libinfo.c and mbt-connect.h and its runner's harness.py), the
# toolchain, the flags (RUSTFLAGS, and the C compiler's, which ring's C code takes: a
# library built without dpkg-buildflags' hardening is not kept for the packages), the
# training's knobs (PGO_TCP_TX, PGO_TLS_TX, PGO_TLS_CASES,
# PGO_RTU_TX). When a library built from exactly these is in DIR, and none of these
# files is changed in the working tree, it is kept (the test run's packaging step would
# otherwise build the same library a second time). Outside a git work tree: always
# built.
paths=(Cargo.toml Cargo.lock build.rs src proto cbindgen abi include benches c-tests/common
    c-tests/tls/make-certs.sh scripts/build-pgo.sh scripts/pgo-rustc.sh scripts/deb-build-env.sh)
inputs=
if git rev-parse --is-inside-work-tree >/dev/null 2>&1 && [ -z "$(git status --porcelain -- "${paths[@]}")" ]; then
    inputs=$({ rustc -vV; echo "RUSTFLAGS=${RUSTFLAGS:-}"
        env | grep -E '^(PGO_[A-Z_]*|SOURCE_DATE_EPOCH|(TARGET_|HOST_)?(CC|CFLAGS|CPPFLAGS|LDFLAGS)(_[a-z0-9_-]*)?)=' |
            LC_ALL=C sort || true
        git ls-files -s -- "${paths[@]}"; } | sha256sum | cut -c1-32)
fi
if [ -n "$inputs" ] && [ "$(cat "$out/inputs" 2>/dev/null)" = "$inputs" ] && [ -e "$out/release/libmodbus.so.5" ]; then
    echo "build-pgo.sh: $out/release is built from these sources already (inputs $inputs): kept"
    exit 0
fi
rm -f "$out/inputs"

# With --target, RUSTFLAGS reach only the library and its dependencies, not the build
# script, cbindgen and its own dependencies: those are neither instrumented (their runs
# would add to the profile) nor rebuilt when the profile changes.
raw=$out/profraw
raw_tls=$out/profraw-tls
# ring is compiled without the profile, instrumented neither (scripts/pgo-rustc.sh: with
# it, LLVM stopped inlining ring's AES-GCM glue). A wrapper of the caller's runs after.
wrapper=$(realpath scripts/pgo-rustc.sh)
if [ "$(realpath -m "${RUSTC_WRAPPER:-/}")" != "$wrapper" ]; then
    export RSMODBUS_RUSTC_WRAPPER=${RUSTC_WRAPPER:-}
fi
export RUSTC_WRAPPER=$wrapper
[ "$(RSMODBUS_RUSTC_WRAPPER= "$wrapper" echo --crate-name ring -Cprofile-use=/p -Copt-level=3)" = "--crate-name ring -Copt-level=3" ] &&
    [ "$(RSMODBUS_RUSTC_WRAPPER= "$wrapper" echo --crate-name x -Cprofile-use=/p)" = "--crate-name x -Cprofile-use=/p" ] ||
    die "scripts/pgo-rustc.sh does not take the profile's flags off ring's alone"
gen=$out/gen/$host/release
rm -rf "$raw" "$raw_tls" "$out"/tls*.proftext "$out"/rsmodbus*.profdata
echo "build-pgo.sh: 1/3 instrumented library ($gen)"
RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-generate=$raw" \
    cargo build --release --locked --lib --quiet --target "$host" --target-dir "$out/gen"

echo "build-pgo.sh: 2/3 training run"
# The programs are built against our own headers and linked with the instrumented
# library, so that Debian's libmodbus-dev is not needed here.
MB_CFLAGS="-I$PWD/include" MB_LDFLAGS="-L$gen" benches/build.sh "$out/bin"
# Without address space randomisation (setarch -R: the processes' personality), where
# it is allowed: the targets of indirect calls are recorded as addresses, and with the
# library at a new address in every process, llvm-profdata named a target in one of
# its processes and not in the others ("** External Symbol **"), a different one from
# run to run (2 of 8 TCP-only trainings gave another profile). At one address: 8 of 8
# the same, every target named.
norandom=()
if setarch "$(uname -m)" -R true 2>/dev/null; then
    norandom=(setarch "$(uname -m)" -R)
else
    echo "build-pgo.sh: setarch -R is not allowed here: the profile may differ from run to run" >&2
fi
"${norandom[@]}" python3 benches/pgo-train.py "$out/bin" "$gen" "$raw_tls"
tls_profile=()
if [ -d "$raw_tls" ]; then
    # The TLS processes' profile, its counts rounded (benches/pgo-train.py --round).
    "$profdata" merge --text -o "$out/tls.proftext" "$raw_tls"
    # ring's functions ran in the TLS training: none may have a count (pgo-rustc.sh).
    if grep -q '_ZN4ring' "$out/tls.proftext"; then
        die "ring's functions have counts in the TLS profile: scripts/pgo-rustc.sh did not apply, or the library instantiates a generic function of ring's"
    fi
    python3 benches/pgo-train.py --round "$out/tls.proftext" "$out/tls-rounded.proftext"
    tls_profile=("$out/tls-rounded.proftext")
fi
"$profdata" merge -o "$out/rsmodbus.profdata" "$raw" "${tls_profile[@]}"
# Cargo rebuilds when RUSTFLAGS change, not when a file they name does: the profile's
# name carries its hash.
profile=$out/rsmodbus-$(sha256sum "$out/rsmodbus.profdata" | cut -c1-16).profdata
mv "$out/rsmodbus.profdata" "$profile"

echo "build-pgo.sh: 3/3 optimised library ($out/release)"
# -pgso=false: the code the training did not run (RTU, ASCII, the rarer function codes)
# is compiled as in a plain build. Optimised for size, as LLVM does by default with a
# profile, it took 10-25% more instructions per RTU transaction than the plain build.
RUSTFLAGS="${RUSTFLAGS:-} -Cprofile-use=$profile -Cllvm-args=-pgso=false" \
    cargo build --release --locked --lib --quiet --target "$host" --target-dir "$out/cargo"
# DIR/release, where the other scripts look, is cargo's DIR/cargo/HOST/release. (Not
# in cargo's own directory: there, release/ holds the build script's build.)
[ -L "$out/release" ] || rm -rf "$out/release"
ln -sfn "cargo/$host/release" "$out/release"
for f in libmodbus.so libmodbus.so.5 libmodbus.a libmodbus.pc; do
    [ -e "$out/release/$f" ] || die "$out/release/$f missing after the build"
done
[ -z "$inputs" ] || echo "$inputs" >"$out/inputs"
echo "build-pgo.sh: $out/release/libmodbus.so ($(stat -c %s "$out/release/libmodbus.so") bytes)"
