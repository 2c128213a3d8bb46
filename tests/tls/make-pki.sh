#!/bin/sh
# SPDX-License-Identifier: MIT
# Makes the certificates of the TLS tests in DIR (created): first by running,
# in order, every ```sh block of docs/security.md (the CA, the gateway, the
# operator and monitor PLCs, the CRL, the controller's certificate robot.* for
# jakasim), exactly as a user would; then the
# certificates only the tests need, with the same CA:
#   norole.*      a client certificate without the role extension
#   intruder.*    role "intruder", which no [roles] line lists
#   expired.*     valid from 2020-01-01 to 2021-01-01
#   revoked.*     revoked in ca.crl
#   other-ca.*, stranger.*   another CA and a client certificate of it
#   gateway2.*    a second gateway certificate (rotation)
#   utf8role.*    role "opérateur" (UTF-8, not ASCII)
#   longrole.*    a role of 5000 bytes: a valid UTF8String, too long
#   ia5role.*     the role as an IA5String, not a UTF8String
#
#   tests/tls/make-pki.sh DIR
set -eu
[ $# -eq 1 ] || { echo "usage: $0 DIR" >&2; exit 2; }
ROOT=$(cd "$(dirname "$0")/../.." && pwd)
mkdir -p "$1"
cd "$1"
awk '/^```sh$/ {on = 1; next} /^```/ {on = 0} on' "$ROOT/docs/security.md" > doc-steps.sh
sh -eu doc-steps.sh >doc-steps.log 2>&1 || { cat doc-steps.log >&2; exit 1; }

# A client certificate signed by ca.cnf's CA: client NAME EXTRA-EXT [ca options]
client() {
    name=$1 ext=$2
    shift 2
    printf 'extendedKeyUsage = clientAuth\n%b' "$ext" > "$name.ext"
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc \
        -subj "/CN=plc-$name" -keyout "$name.key" -out "$name.csr" 2>/dev/null
    openssl ca -config ca.cnf -batch -notext -extfile "$name.ext" -in "$name.csr" \
        -out "$name.crt" "$@" 2>/dev/null
}
client norole ''
client intruder '1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:intruder\n'
client expired '1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:operator\n' \
    -startdate 20200101000000Z -enddate 20210101000000Z
client revoked '1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:operator\n'
client utf8role '1.3.6.1.4.1.50316.802.1 = ASN1:FORMAT:UTF8,UTF8String:op\303\251rateur\n'
client longrole "1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:$(head -c 5000 /dev/zero | tr '\0' a)\n"
client ia5role '1.3.6.1.4.1.50316.802.1 = ASN1:IA5String:operator\n'
openssl ca -config ca.cnf -revoke revoked.crt 2>/dev/null
openssl ca -config ca.cnf -gencrl -out ca.crl 2>/dev/null

openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc -days 3650 \
    -subj "/CN=Other CA" -keyout other-ca.key -out other-ca.crt 2>/dev/null
printf 'extendedKeyUsage = clientAuth\n1.3.6.1.4.1.50316.802.1 = ASN1:UTF8String:operator\n' > stranger.ext
openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc \
    -subj "/CN=plc-stranger" -keyout stranger.key -out stranger.csr 2>/dev/null
openssl x509 -req -in stranger.csr -CA other-ca.crt -CAkey other-ca.key -CAcreateserial \
    -days 825 -extfile stranger.ext -out stranger.crt 2>/dev/null

for name in gateway2; do
    openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -noenc \
        -subj "/CN=$name" -keyout "$name.key" -out "$name.csr" 2>/dev/null
    openssl ca -config ca.cnf -batch -notext -extfile gateway.ext -in "$name.csr" \
        -out "$name.crt" 2>/dev/null
done
chmod 600 ./*.key
