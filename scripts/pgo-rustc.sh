#!/bin/sh
# pgo-rustc.sh: the RUSTC_WRAPPER of scripts/build-pgo.sh. It runs rustc (its first
# argument) with the rest, except that the crate ring is compiled without the
# profile's flags (-Cprofile-generate, -Cprofile-use): as in a plain release build.
# Why: with the profile, LLVM stopped inlining ring's AES-GCM glue into its callers
# (Overlapping::with_input_output_len, called three times per record sealed or
# opened), which cost 244 instructions more per TLS transaction of read 125 registers
# on the client than the plain build (callgrind), 6.5% of it. The training cannot
# make ring faster: its AES-GCM is assembly, which a profile does not change.
# RSMODBUS_RUSTC_WRAPPER: a wrapper of the caller's own (sccache...), run after this.
# SPDX-License-Identifier: MIT OR Apache-2.0
rustc=$1
shift
crate=
prev=
for arg in "$@"; do
    [ "$prev" = --crate-name ] && crate=$arg
    prev=$arg
done
if [ "$crate" = ring ]; then
    n=$#
    while [ "$n" -gt 0 ]; do
        arg=$1
        shift
        n=$((n - 1))
        case $arg in
            -Cprofile-generate=* | -Cprofile-use=*) ;;
            *) set -- "$@" "$arg" ;;
        esac
    done
fi
exec ${RSMODBUS_RUSTC_WRAPPER:+"$RSMODBUS_RUSTC_WRAPPER"} "$rustc" "$@"
