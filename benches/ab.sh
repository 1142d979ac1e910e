#!/usr/bin/env bash
# A/B throughput of two revisions of rsmodbus (benches/ab.py), pinned to CPU 1:
#
#   benches/ab.sh A B [CASE ...]
#
# A and B are git revisions, each optionally followed by ":PATCH" (patch files applied
# on top, several separated by ":"), e.g.
#   benches/ab.sh 015e764 015e764:benches/experiments/lean-tcp-fc23-client.patch
# Each is built as a release library in a git worktree under target/ab/. The C programs
# are those of the working tree. BENCH_SECONDS (default 30) per pairing; default case wr121.
#
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 2 ] || { sed -n '2,11p' "$0"; exit 2; }
scripts/install-deps.sh >/dev/null
for tool in socat python3 gcc; do
    command -v "$tool" >/dev/null || { apt-get install -y -qq "$tool" >/dev/null; }
done
benches/build.sh target/bench

# Worktrees left by a build that failed are removed on the way out.
cleanup() { for n in a b; do git worktree remove --force "target/ab/$n/src" 2>/dev/null || true; done; }
trap cleanup EXIT

# build SPEC NAME: the library of SPEC (REV[:PATCH...]) in target/ab/NAME/lib. The
# target directory is kept between runs, so only the library itself is rebuilt.
build() {
    local dir=$PWD/target/ab/$2 rev patches=() p
    IFS=: read -r -a patches <<< "$1"
    rev=${patches[0]}
    patches=("${patches[@]:1}")
    git worktree remove --force "$dir/src" 2>/dev/null || true
    git worktree prune
    rm -rf "$dir/src" "$dir/lib"
    git worktree add -q --detach "$dir/src" "$rev"
    for p in "${patches[@]}"; do
        git -C "$dir/src" apply "$(realpath "$p")"
    done
    cargo build -q --release --lib --manifest-path "$dir/src/Cargo.toml" --target-dir "$dir/target"
    mkdir -p "$dir/lib"
    cp "$dir/target/release/libmodbus.so" "$dir/lib/libmodbus.so.5"
    git worktree remove --force "$dir/src"
}
build "$1" a
build "$2" b
shift 2
trap - EXIT
BENCH_PIN=${BENCH_PIN-1} exec python3 benches/ab.py target/ab/a/lib target/ab/b/lib "$@"
