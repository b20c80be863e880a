"""Container health checks for docker-compose.yml (the image has Python but no curl).

``python healthcheck.py coordinator``: GET /healthz on this container answers 200.
``python healthcheck.py node``: the coordinator (from TESSERA_COORDINATOR) lists this node in
/api/stats, i.e. the node is connected and registered, not merely running. A node is recognised by
its name: TESSERA_NAME when set and expanded (Swarm's template), else its container's name as the
node takes it from Docker's DNS (node/container_name.py), else its default ``<hostname>-<pid>``.
Exit status 0 is healthy, 1 unhealthy (the reason goes to stderr, which ``docker inspect`` shows).
"""

from __future__ import annotations

import json
import os
import socket
import sys
import urllib.parse
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # the image's /app: the node package

from node.container_name import container_name, is_unexpanded_template

TIMEOUT_S = 4.0


def get(url: str) -> bytes:
    request = urllib.request.Request(url)
    token = os.environ.get("TESSERA_TOKEN")
    if token:
        request.add_header("Authorization", f"Bearer {token}")
    with urllib.request.urlopen(request, timeout=TIMEOUT_S) as response:
        return response.read()


def coordinator_healthy() -> None:
    get("http://127.0.0.1:8000/healthz")


def node_registered() -> None:
    ws_url = urllib.parse.urlsplit(os.environ.get("TESSERA_COORDINATOR", "ws://127.0.0.1:8000/ws/node"))
    scheme = "https" if ws_url.scheme == "wss" else "http"
    stats = json.loads(get(f"{scheme}://{ws_url.netloc}/api/stats"))
    names = [node.get("name", "") for node in stats.get("nodes", [])]
    given = os.environ.get("TESSERA_NAME")
    own_name = given if given and not is_unexpanded_template(given) else container_name()
    prefix = socket.gethostname() + "-"
    if not any(name == own_name or (not own_name and name.startswith(prefix)) for name in names):
        raise RuntimeError(f"not among the coordinator's nodes {names}")


def main(role: str) -> int:
    check = {"coordinator": coordinator_healthy, "node": node_registered}[role]
    try:
        check()
    except Exception as exc:  # any failure is "unhealthy", with the reason for docker inspect
        print(f"{role} unhealthy: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
