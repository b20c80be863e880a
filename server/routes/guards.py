"""What every coordinator WebSocket passes (``/ws/view``, ``/ws/node``), and every request that
changes something (``POST``/``PUT``/``DELETE``…).

* **Watch keys**: a request that may change something and names a session by its watch key (in
  ``/api/sessions/KEY/…``, or in the ``X-Tessera-Watch`` header the watch page sends with every
  call) gets a JSON 403 with the reason: a watch link shows a session and changes nothing.
* **Origin**, before the handshake: a browser page of another origin gets HTTP 403 with the reason
  (``server/origins.py``: same origin, ``--allowed-origins``, no ``Origin`` header for non-browsers).
  Requests other than GET, HEAD and OPTIONS get the same check (cross-site request forgery: a page
  elsewhere may send a form-like ``POST`` without a preflight), answered by a JSON 403.
* **Message size and rate**, on every message received: over ``--max-*-message-bytes`` closes with
  1009, over ``--max-*-messages-per-s`` (a token bucket holding a second's worth) with 1008; the
  reason names the limit and its flag.

Each refusal is logged as one line.
"""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import time
from typing import Any
from urllib.parse import unquote

from fastapi import Request, WebSocket
from fastapi.responses import JSONResponse, PlainTextResponse, Response
from starlette.middleware.base import RequestResponseEndpoint

from server.origins import own_origin
from tessera.wire.token_bucket import TokenBucket

log = logging.getLogger("tessera.server")

#: WebSocket close reasons are at most 123 bytes.
MAX_CLOSE_REASON = 120


def peer(ws: WebSocket) -> str:
    return f"{ws.client.host}:{ws.client.port}" if ws.client else "unknown peer"


def loopback(ws: WebSocket) -> bool:
    """The peer connected from this machine (a loopback address)."""
    try:
        return ws.client is not None and ipaddress.ip_address(ws.client.host).is_loopback
    except ValueError:   # not an IP address (a test client's name)
        return False


async def close(ws: WebSocket, code: int, reason: str) -> None:
    """Close with ``code`` and ``reason`` (cut to fit a close frame); nothing if already closed."""
    with contextlib.suppress(RuntimeError):
        await ws.close(code, reason.encode()[:MAX_CLOSE_REASON].decode(errors="ignore"))


def origin_refusal(connection: Request | WebSocket) -> str | None:
    """Why the page behind this request or handshake (if a page) may not use it, or None."""
    headers = connection.headers
    own = own_origin(connection.url.scheme, headers.get("host"), headers.get("x-forwarded-proto"),
                     headers.get("x-forwarded-host"))
    return connection.app.state.origins.refusal(headers.get("origin"), own)


#: Methods that change nothing: a page elsewhere may read what CORS lets it, never write.
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})


async def refuse_cross_site_writes(request: Request, call_next: RequestResponseEndpoint) -> Response:
    """HTTP middleware: a request that may change something, sent by a page of another origin, gets
    403 with the reason (logged) instead of reaching its route."""
    reason = None if request.method in SAFE_METHODS else origin_refusal(request)
    if reason is None:
        return await call_next(request)
    log.warning("%s %s from %s refused: %s", request.method, request.url.path,
                f"{request.client.host}:{request.client.port}" if request.client else "unknown peer", reason)
    return JSONResponse({"detail": reason}, status_code=403)


#: What a change made with a watch key is told.
WATCH_KEYS_CHANGE_NOTHING = ("this is a watch link: it shows the session and changes nothing "
                             "(the session's drive link steers it)")
#: The header the watch page names its watch key in, on every API call.
WATCH_HEADER = "x-tessera-watch"
SESSIONS_PATH = "/api/sessions/"


def watch_key_of(request: Request) -> str | None:
    """The watch key the request presents (its ``X-Tessera-Watch`` header, or a session's watch key
    in place of its id in ``/api/sessions/KEY/…``), or None."""
    if (header := request.headers.get(WATCH_HEADER)) is not None:
        return header
    path = request.url.path.removeprefix(request.scope.get("root_path", "") or "")
    if not path.startswith(SESSIONS_PATH):
        return None
    key = unquote(path[len(SESSIONS_PATH):].split("/", 1)[0])
    return key if request.app.state.service.find_session(key, watch=True) is not None else None


async def refuse_watch_writes(request: Request, call_next: RequestResponseEndpoint) -> Response:
    """HTTP middleware: a request that may change something, made with a watch key, gets 403 with
    :data:`WATCH_KEYS_CHANGE_NOTHING` instead of reaching its route."""
    if request.method in SAFE_METHODS or watch_key_of(request) is None:
        return await call_next(request)
    log.info("%s %s refused: made with a watch key", request.method, request.url.path)
    return JSONResponse({"detail": WATCH_KEYS_CHANGE_NOTHING}, status_code=403)


async def admit_origin(ws: WebSocket, what: str) -> bool:
    """True when the page that opens ``ws`` (if a page does) may; else answers 403 with the reason
    before the handshake and logs it."""
    reason = origin_refusal(ws)
    if reason is None:
        return True
    log.warning("%s socket from %s refused: %s", what, peer(ws), reason)
    try:
        await ws.send_denial_response(PlainTextResponse(reason + "\n", status_code=403))
    except RuntimeError:  # a server without the denial-response extension: a plain 403
        await ws.close(1008, reason[:MAX_CLOSE_REASON])
    return False


class SocketLimits:
    """One socket's message limits: at most ``max_bytes`` a message and ``rate`` messages per
    second, a second's worth at once (``rate`` 0: no rate limit). Pure: ``now`` is passed in."""

    def __init__(self, kind: str, max_bytes: int, rate: float, now: float) -> None:
        self.kind = kind
        self.max_bytes = max_bytes
        self.rate = rate
        self.bucket = TokenBucket(rate, max(rate, 1.0), now) if rate > 0 else None

    def refusal(self, message: dict[str, Any], now: float) -> tuple[int, str] | None:
        """(close code, reason) when the ASGI ``message`` breaks a limit, else None."""
        data, text = message.get("bytes"), message.get("text")
        if data is not None:
            size = len(data)
        elif text is not None:
            size = len(text) if 4 * len(text) <= self.max_bytes else len(text.encode())
        else:
            size = 0
        if size > self.max_bytes:
            return 1009, f"message of {size} bytes over the limit of {self.max_bytes} (--max-{self.kind}-message-bytes)"
        if self.bucket is not None and not self.bucket.take(now):
            return 1008, f"over {self.rate:g} messages/s (--max-{self.kind}-messages-per-s)"
        return None


def limits_for(ws: WebSocket, kind: str) -> SocketLimits:
    """The limits of a ``kind`` ("viewer" or "node") socket, from the settings."""
    settings = ws.app.state.settings
    if kind == "node":
        return SocketLimits(kind, settings.node_message_bytes, settings.max_node_messages_per_s, time.monotonic())
    return SocketLimits(kind, settings.max_viewer_message_bytes, settings.max_viewer_messages_per_s, time.monotonic())


async def receive(ws: WebSocket, limits: SocketLimits, who: str) -> dict[str, Any] | None:
    """The next message; None when the peer left, or broke a limit (then logged and closed with the
    reason)."""
    message = await ws.receive()
    if message["type"] == "websocket.disconnect":
        return None
    refused = limits.refusal(message, time.monotonic())
    if refused is None:
        return message
    code, reason = refused
    log.warning("%s (%s) closed: %s", who, peer(ws), reason)
    await close(ws, code, reason)
    return None


def viewers_full(count: int, limit: int) -> str | None:
    """Why one more viewer is refused when ``count`` are connected (``limit`` 0: no limit)."""
    if limit and count >= limit:
        return f"too many viewers: {count} of {limit} (--max-viewers)"
    return None
