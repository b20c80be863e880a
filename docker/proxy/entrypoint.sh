#!/bin/sh
# Start nginx with the certificate mounted at /certs (cert.pem and key.pem, from TESSERA_TLS_DIR) or,
# when that folder holds neither, a self-signed one made now for TESSERA_TLS_NAMES (comma-separated
# host names and IP addresses, default localhost; 127.0.0.1 and ::1 are always in it).
set -eu
tls=/tmp/tls
mkdir -p "$tls" /tmp/nginx

if [ -d /certs ] && ! { [ -r /certs ] && [ -x /certs ]; }; then
    echo "proxy: /certs (TESSERA_TLS_DIR) is not readable by uid $(id -u)" >&2
    exit 1
fi
if [ -e /certs/cert.pem ] || [ -e /certs/key.pem ]; then
    for file in cert.pem key.pem; do
        if [ ! -r "/certs/$file" ]; then
            echo "proxy: /certs/$file (TESSERA_TLS_DIR) is missing or not readable by uid $(id -u)" >&2
            exit 1
        fi
        ln -sf "/certs/$file" "$tls/$file"
    done
    echo "proxy: certificate from TESSERA_TLS_DIR"
else
    names="${TESSERA_TLS_NAMES:-localhost}"
    san=""
    for name in $(echo "$names" | tr ',' ' ') 127.0.0.1 ::1; do
        case "$name" in
            *:*) kind=IP ;;
            *[!0-9.]*) kind=DNS ;;
            *) kind=IP ;;
        esac
        san="${san:+$san,}$kind:$name"
    done
    first="$(echo "$names" | cut -d, -f1)"
    openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:prime256v1 -nodes -days 365 \
        -subj "/CN=$first" -addext "subjectAltName=$san" \
        -keyout "$tls/key.pem" -out "$tls/cert.pem" 2>/dev/null
    echo "proxy: no cert.pem/key.pem in TESSERA_TLS_DIR: self-signed certificate for $san," \
        "$(openssl x509 -in "$tls/cert.pem" -noout -fingerprint -sha256)"
fi

exec nginx -e stderr -g "daemon off;"
