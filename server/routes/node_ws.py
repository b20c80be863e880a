"""``WS /ws/node``: render nodes. First a ``hello`` (token checked), then control JSON and binary
tiles. Anything malformed closes that node's connection with a reason; the loop keeps running
and the node's owed tiles move to the others."""

from __future__ import annotations

import asyncio
import contextlib
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.nodes import NodeLink
from server.routes.deps import token_ok
from server.service import RenderService
from tessera.messages import FROM_NODE, NodeHello, parse
from tessera.protocol import ProtocolError

router = APIRouter()
log = logging.getLogger("tessera.server")

HELLO_TIMEOUT_S = 15.0


async def _close(ws: WebSocket, code: int, reason: str) -> None:
    with contextlib.suppress(RuntimeError):
        await ws.close(code, reason.encode()[:120].decode(errors="ignore"))


async def _read_hello(ws: WebSocket, token: str | None) -> NodeHello | None:
    try:
        first = await asyncio.wait_for(ws.receive(), HELLO_TIMEOUT_S)
    except TimeoutError:
        await _close(ws, 1008, f"no hello within {HELLO_TIMEOUT_S:.0f} s")
        return None
    if first["type"] == "websocket.disconnect":
        return None
    try:
        if first.get("text") is None:
            raise ProtocolError("the first message must be a JSON hello")
        hello = parse(first["text"], [NodeHello])
    except ProtocolError as exc:
        log.warning("node refused: %s", exc)
        await _close(ws, 1008, str(exc))
        return None
    if not token_ok(token, hello.token):
        log.warning("node %r refused: wrong token", hello.name)
        await _close(ws, 4401, "wrong token")
        return None
    return hello


async def _write(ws: WebSocket, link: NodeLink) -> None:
    while True:
        await ws.send_text(await link.outbox.get())


@router.websocket("/ws/node")
async def node_socket(ws: WebSocket) -> None:
    service: RenderService = ws.app.state.service
    await ws.accept()
    hello = await _read_hello(ws, ws.app.state.settings.token)
    if hello is None:
        return
    link = service.add_node(hello, lambda code, reason: asyncio.create_task(_close(ws, code, reason)))
    writer = asyncio.create_task(_write(ws, link))
    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            if message.get("bytes") is not None:
                service.on_tile_message(link, message["bytes"])
            else:
                service.on_node_message(link, parse(message.get("text") or "", FROM_NODE))
    except ProtocolError as exc:
        log.warning("node %d (%s) broke the protocol: %s; closing it", link.node_id, link.name, exc)
        await _close(ws, 1008, str(exc))
    except (WebSocketDisconnect, RuntimeError):
        pass
    except Exception:
        log.exception("node %d (%s): unexpected error; closing it", link.node_id, link.name)
        await _close(ws, 1011, "internal error")
    finally:
        writer.cancel()
        service.remove_node(link)
