"""The notebook tests' own helper: a page that cannot reach a given address (the coordinator is
reachable only from the kernel). ``jupyter lab`` itself: :mod:`bench.jupyter`."""

from __future__ import annotations

import re
from typing import Any


def blocking(context: Any, host_port: str) -> list[str]:
    """Make ``host_port`` unreachable from the pages of ``context`` (HTTP and WebSocket): every
    attempt is refused and listed in the list returned."""
    attempts: list[str] = []
    pattern = re.compile(rf"^(https?|wss?)://{re.escape(host_port)}/")

    def refuse(route: Any) -> None:
        attempts.append(route.request.url)
        route.abort()

    def refuse_socket(ws: Any) -> None:
        attempts.append(ws.url)
        ws.close()

    context.route(pattern, refuse)
    context.route_web_socket(pattern, refuse_socket)
    return attempts
