#!/bin/sh
# Healthy when GET /healthz over TLS on this container answers 200, i.e. TLS and the coordinator behind it.
printf 'GET /healthz HTTP/1.0\r\nHost: localhost\r\n\r\n' \
    | timeout 4 openssl s_client -quiet -connect 127.0.0.1:8443 2>/dev/null \
    | head -n 1 | grep -q '^HTTP/1\.[01] 200 '
