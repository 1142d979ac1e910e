#!/usr/bin/env bash
# suites.sh CERTS PORT: our TLS server on PORT (examples/tls-server.c's map: register A
# holds 1000 + A) against openssl s_client in every cipher suite of TLS 1.2 and 1.3,
# two requests in records of their own; over TLS 1.3 the client asks for a key update
# between them (s_client's command K), so that the second request comes under its next
# key and the answer under ours. Prints one PASS/FAIL line per suite, and one for the
# choice among suites: the server takes the client's order (s_client offering AES-256
# first gets it, while our own client asks for AES-128 first).
# SPDX-License-Identifier: MIT OR Apache-2.0
set -uo pipefail
C=$1 PORT=$2
py() { python3 -c "import signal, struct, sys; signal.signal(signal.SIGPIPE, signal.SIG_DFL); $1"; }
request() { py "sys.stdout.buffer.write(struct.pack('>HHHBBHH', $1, 0, 6, 1, 3, 4 + $1, 1))"; }
answer() { py "sys.stdout.buffer.write(struct.pack('>HHHBBBH', $1, 0, 5, 1, 3, 2, 1004 + $1))" | xxd -p; }
run() { # run NAME BETWEEN ARGS...: BETWEEN is typed to s_client between the requests
    local name=$1 between=$2
    shift 2
    local out
    out=$({ request 1; sleep 0.3; printf '%b' "$between"; sleep 0.3; request 2; sleep 0.5; } |
        timeout 10 openssl s_client -connect "127.0.0.1:$PORT" -CAfile "$C/ca.pem" -cert "$C/operator.pem" \
            -key "$C/operator.key" "$@" 2>/dev/null | xxd -p | tr -d '\n')
    local first=no second=no
    [[ $out == *"$(answer 1)"* ]] && first=yes
    [[ $out == *"$(answer 2)"* ]] && second=yes
    if [ $first = yes ] && [ $second = yes ]; then
        echo "PASS $name: both answers"
    else
        echo "FAIL $name: first answer $first, second $second"
    fi
}
for suite in ECDHE-ECDSA-AES128-GCM-SHA256 ECDHE-ECDSA-AES256-GCM-SHA384 ECDHE-ECDSA-CHACHA20-POLY1305; do
    run "TLS 1.2 $suite" "" -tls1_2 -cipher "$suite"
done
for suite in TLS_AES_128_GCM_SHA256 TLS_AES_256_GCM_SHA384 TLS_CHACHA20_POLY1305_SHA256; do
    run "TLS 1.3 $suite, a key update between the requests" 'K\n' -tls1_3 -ciphersuites "$suite"
done
order=$(echo | timeout 10 openssl s_client -connect "127.0.0.1:$PORT" -CAfile "$C/ca.pem" -cert "$C/operator.pem" \
    -key "$C/operator.key" -tls1_3 -ciphersuites TLS_AES_256_GCM_SHA384:TLS_AES_128_GCM_SHA256 -brief 2>&1 |
    sed -n 's/^Ciphersuite: //p')
if [ "$order" = TLS_AES_256_GCM_SHA384 ]; then
    echo "PASS the client's order: TLS_AES_256_GCM_SHA384 offered first is taken"
else
    echo "FAIL the client's order: TLS_AES_256_GCM_SHA384 offered first, '$order' taken"
fi
