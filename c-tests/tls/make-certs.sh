#!/usr/bin/env bash
# make-certs.sh DIR: the certificates of the TLS tests, made with openssl (P-256 keys):
#   ca.pem/ca.key            the test CA
#   server.pem/.key          server for loopback (IP:127.0.0.1, IP:::1, DNS:localhost)
#   wrongname.pem/.key       server certificate for another name and address
#   operator.pem/.key        client, role "Operator"
#   reader.pem/.key          client, role "Reader"
#   norole.pem/.key          client without a role
#   rogue-ca.pem, rogue.pem/.key   another CA, and a client it issued (role Operator)
#   expired.pem/.key         client of the test CA, valid 2019-2020 (role Operator)
#   operator-aes.key         operator.key encrypted with the password "secret": PKCS#8,
#                            PBES2 (PBKDF2-HMAC-SHA256, AES-256-CBC)
#   operator-scrypt.key      the same with scrypt
#   operator-pbes1.key       the same with PBES1 (SHA-1, 3DES): not supported
#   operator-sha1.key        PBES2 with PBKDF2-HMAC-SHA-1: not supported
#   operator-legacy.key      OpenSSL's older encrypted PEM (Proc-Type): not supported
# SPDX-License-Identifier: MIT OR Apache-2.0
set -euo pipefail
D=$1
mkdir -p "$D"
cd "$D"
key() { openssl genpkey -algorithm EC -pkeyopt ec_paramgen_curve:P-256 -out "$1" 2>/dev/null; }
ca() { # name subject
    key "$1.key"
    openssl req -x509 -new -key "$1.key" -subj "/CN=$2" -days 3650 -sha256 -out "$1.pem" \
        -addext "basicConstraints=critical,CA:TRUE" -addext "keyUsage=critical,keyCertSign,cRLSign"
}
leaf() { # name cn ca extfile-lines...
    local name=$1 cn=$2 issuer=$3
    shift 3
    key "$name.key"
    openssl req -new -key "$name.key" -subj "/CN=$cn" -out "$name.csr"
    printf '%s\n' "basicConstraints=CA:FALSE" "$@" >"$name.ext"
    openssl x509 -req -in "$name.csr" -CA "$issuer.pem" -CAkey "$issuer.key" -CAcreateserial \
        -days 825 -sha256 -extfile "$name.ext" -out "$name.pem" 2>/dev/null
}
role() { echo "1.3.6.1.4.1.50316.802.1=ASN1:UTF8String:$1"; }
ca ca "rsmodbus test CA"
ca rogue-ca "another CA"
leaf server localhost ca "subjectAltName=IP:127.0.0.1,IP:::1,DNS:localhost" "extendedKeyUsage=serverAuth"
leaf wrongname wrong.example ca "subjectAltName=DNS:wrong.example,IP:10.9.9.9" "extendedKeyUsage=serverAuth"
leaf operator operator ca "$(role Operator)" "extendedKeyUsage=clientAuth"
leaf reader reader ca "$(role Reader)" "extendedKeyUsage=clientAuth"
leaf norole norole ca "extendedKeyUsage=clientAuth"
leaf rogue rogue rogue-ca "$(role Operator)" "extendedKeyUsage=clientAuth"
# Expired: `openssl ca` sets the validity dates (x509 -req cannot).
mkdir -p expired-ca/newcerts
: >expired-ca/index.txt
echo 01 >expired-ca/serial
cat >expired-ca/ca.cnf <<CNF
[ca]
default_ca = test
[test]
dir = expired-ca
database = \$dir/index.txt
new_certs_dir = \$dir/newcerts
serial = \$dir/serial
default_md = sha256
policy = any
copy_extensions = none
[any]
commonName = supplied
[ext]
basicConstraints = CA:FALSE
extendedKeyUsage = clientAuth
$(role Operator)
CNF
key expired.key
openssl req -new -key expired.key -subj "/CN=expired" -out expired.csr
openssl ca -batch -config expired-ca/ca.cnf -cert ca.pem -keyfile ca.key -in expired.csr -out expired.pem \
    -startdate 20190101000000Z -enddate 20200101000000Z -extensions ext -notext 2>/dev/null
openssl pkcs8 -topk8 -v2 aes-256-cbc -in operator.key -passout pass:secret -out operator-aes.key
openssl pkcs8 -topk8 -scrypt -in operator.key -passout pass:secret -out operator-scrypt.key
openssl pkcs8 -topk8 -v1 PBE-SHA1-3DES -in operator.key -passout pass:secret -out operator-pbes1.key
openssl pkcs8 -topk8 -v2 aes-256-cbc -v2prf hmacWithSHA1 -in operator.key -passout pass:secret \
    -out operator-sha1.key
openssl ec -aes256 -in operator.key -passout pass:secret -out operator-legacy.key 2>/dev/null
rm -f ./*.csr ./*.ext ./*.srl
