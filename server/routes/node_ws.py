"""``WS /ws/node``: render nodes. First a ``hello`` (token checked), then control JSON and binary
tiles. Anything malformed closes that node's connection with a reason; the loop keeps running
and the node's owed tiles move to the others. Pages of other origins and sockets over their message
size or rate are refused (``server/routes/guards.py``)."""

from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.nodes import NodeLink
from server.routes import guards
from server.routes.deps import token_ok
from server.service import RenderService
from tessera.wire.messages import FROM_NODE, NodeHello, parse
from tessera.wire.pick_messages import FROM_NODE_PICKS
from tessera.wire.protocol import ProtocolError

router = APIRouter()
log = logging.getLogger("tessera.server")

HELLO_TIMEOUT_S = 15.0


async def _read_hello(ws: WebSocket, token: str | None, limits: guards.SocketLimits) -> NodeHello | None:
    try:
        first = await asyncio.wait_for(guards.receive(ws, limits, "node"), HELLO_TIMEOUT_S)
    except TimeoutError:
        await guards.close(ws, 1008, f"no hello within {HELLO_TIMEOUT_S:.0f} s")
        return None
    if first is None:
        return None
    try:
        if first.get("text") is None:
            raise ProtocolError("the first message must be a JSON hello")
        hello = parse(first["text"], [NodeHello])
    except ProtocolError as exc:
        log.warning("node refused: %s", exc)
        await guards.close(ws, 1008, str(exc))
        return None
    if not token_ok(token, hello.token):
        log.warning("node %r refused: wrong token", hello.name)
        await guards.close(ws, 4401, "wrong token")
        return None
    return hello


async def _write(ws: WebSocket, link: NodeLink) -> None:
    while True:
        message = await link.outbox.get()
        if isinstance(message, bytes):
            await ws.send_bytes(message)
        else:
            await ws.send_text(message)


@router.websocket("/ws/node")
async def node_socket(ws: WebSocket) -> None:
    service: RenderService = ws.app.state.service
    if not await guards.admit_origin(ws, "node"):
        return
    await ws.accept()
    limits = guards.limits_for(ws, "node")
    hello = await _read_hello(ws, ws.app.state.settings.token, limits)
    if hello is None:
        return
    refusal = service.refusal(hello)
    if refusal is not None:
        log.warning("node %r refused: %s", hello.name, refusal)
        await guards.close(ws, 1008, refusal)
        return
    link = service.add_node(hello, lambda code, reason: asyncio.create_task(guards.close(ws, code, reason)),
                            local=guards.loopback(ws))
    writer = asyncio.create_task(_write(ws, link))
    who = f"node {link.node_id} ({link.name})"
    try:
        while True:
            message = await guards.receive(ws, limits, who)
            if message is None:
                break
            if message.get("bytes") is not None:
                service.on_tile_message(link, message["bytes"])
            else:
                service.on_node_message(link, parse(message.get("text") or "", (*FROM_NODE, *FROM_NODE_PICKS)))
    except ProtocolError as exc:
        log.warning("node %d (%s) broke the protocol: %s; closing it", link.node_id, link.name, exc)
        await guards.close(ws, 1008, str(exc))
    except (WebSocketDisconnect, RuntimeError):
        pass
    except Exception:
        log.exception("node %d (%s): unexpected error; closing it", link.node_id, link.name)
        await guards.close(ws, 1011, "internal error")
    finally:
        writer.cancel()
        service.remove_node(link)
