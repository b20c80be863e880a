"""A real reverse proxy for the prefix tests: Debian's nginx serving a coordinator under a path
prefix (``location /tessera/``, the prefix stripped, WebSockets upgraded, ``X-Forwarded-Prefix``
set), as a user's proxy in front of JupyterHub or a cluster's web server would."""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Iterator
from pathlib import Path

from bench.jupyter import free_port, wait_answering
from bench.processes import LoggedProcess
from tests.browser_support import unavailable

NGINX_CONFIG = """daemon off;
worker_processes 1;
pid {root}/nginx.pid;
error_log stderr warn;
events {{ worker_connections 256; }}
http {{
  access_log off;
  client_body_temp_path {root}/body;
  proxy_temp_path {root}/proxy;
  fastcgi_temp_path {root}/fastcgi;
  uwsgi_temp_path {root}/uwsgi;
  scgi_temp_path {root}/scgi;
  client_max_body_size 600m;
  map $http_upgrade $connection_upgrade {{ default upgrade; '' close; }}
  server {{
    listen 127.0.0.1:{port};
    location {prefix}/ {{
      proxy_pass http://{upstream}/;
      proxy_http_version 1.1;
      proxy_set_header Upgrade $http_upgrade;
      proxy_set_header Connection $connection_upgrade;
      proxy_set_header Host $http_host;
      proxy_set_header X-Forwarded-Prefix {prefix};
      proxy_buffering off;
      proxy_request_buffering off;
      proxy_read_timeout 300s;
    }}
  }}
}}
"""


def nginx_binary() -> str:
    found = shutil.which("nginx") or next((p for p in ("/usr/sbin/nginx",) if Path(p).exists()), None)
    if found is None:
        unavailable("nginx is missing (apt-get install nginx-light; scripts/test installs it)")
    assert found is not None
    return found


@contextlib.contextmanager
def nginx_prefix(upstream: str, prefix: str, root: Path, timeout: float) -> Iterator[str]:
    """nginx serving ``upstream`` (``host:port``) under ``prefix`` (``/tessera``); yields the
    proxied base URL (``http://127.0.0.1:PORT/tessera/``)."""
    root.mkdir(parents=True, exist_ok=True)
    port = free_port()
    config = root / "nginx.conf"
    config.write_text(NGINX_CONFIG.format(root=root, port=port, prefix=prefix, upstream=upstream))
    proc = LoggedProcess([nginx_binary(), "-c", str(config), "-p", str(root)], new_session=True, stop_timeout=timeout)
    url = f"http://127.0.0.1:{port}{prefix}/"
    try:
        wait_answering(proc, f"{url}healthz", timeout, "nginx")
        yield url
    finally:
        proc.stop()
