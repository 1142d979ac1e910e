#!/usr/bin/env bash
# The main job: build the library, then run the example client against the example
# server on loopback, both loading this library, and print what they exchanged.
set -euo pipefail
cd "$(dirname "$0")/.."
command -v gcc >/dev/null || { apt-get update -qq && apt-get install -y -qq gcc >/dev/null; }
cargo build --release
lib="$PWD/target/release"
ln -sf libmodbus.so "$lib/libmodbus.so.5"
out="$PWD/target/examples"
mkdir -p "$out"
for prog in tcp-server tcp-client; do
    gcc -Wall -Wextra -Werror -Iinclude "examples/$prog.c" -L"$lib" -lmodbus -Wl,-rpath,"$lib" -o "$out/$prog"
done
echo "== client loads: $(ldd "$out/tcp-client" | grep 'libmodbus.so.5')"

port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
# The client sends 5 requests; the server stops after serving them.
"$out/tcp-server" "$port" 5 > "$out/server.log" 2>&1 &
server=$!
trap 'kill "$server" 2>/dev/null || true' EXIT
for _ in $(seq 50); do grep -q serving "$out/server.log" 2>/dev/null && break; sleep 0.1; done
"$out/tcp-client" 127.0.0.1 "$port"
wait "$server"
trap - EXIT
echo "== server: $(tail -n 1 "$out/server.log")"
python3 man/gen-man.py --out target/man >/dev/null
echo "== the manual: man -M target/man modbus_new_tcp_tls   (or: export MANPATH=$PWD/target/man:)"
