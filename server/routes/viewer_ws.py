"""``WS /ws/view``: browsers. Each viewer gets a latest-frame slot and its own sender task;
it sends camera JSON back. Invalid input gets an ``error`` message, never a crash."""

from __future__ import annotations

import asyncio
import logging

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.routes.balancer import BALANCERS
from server.routes.deps import presented_token, token_ok
from server.service import RenderService
from server.viewers import ViewerSlot
from tessera.geometry import Camera, CameraError
from tessera.protocol import ProtocolError, decode_json

router = APIRouter()
log = logging.getLogger("tessera.server")


async def _send(ws: WebSocket, slot: ViewerSlot) -> None:
    while True:
        message = await slot.next_message()
        if isinstance(message, str):
            await ws.send_text(message)
        else:
            await ws.send_bytes(message)


@router.websocket("/ws/view")
async def viewer_socket(ws: WebSocket) -> None:
    service: RenderService = ws.app.state.service
    await ws.accept()
    if not token_ok(ws.app.state.settings.token, presented_token(ws)):
        await ws.close(4401, "wrong token")
        return
    slot = service.viewers.join()
    slot.put_control({
        "type": "hello", "size": list(service.size),
        "camera": service.camera.to_json() if service.camera else None,
        "bounds": service.bounds.tolist() if service.bounds is not None else None,
        "balancer": service.balancer.name, "balancers": sorted(BALANCERS), "frame": service.store.last_id,
    })
    if service.store.latest is not None:
        slot.put_frame(service.store.latest.viewer_message)
    sender = asyncio.create_task(_send(ws, slot))
    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            try:
                request = decode_json(message.get("text") or "", ["camera"])
                camera = Camera.from_json(request.get("camera"))
            except (ProtocolError, CameraError) as exc:
                log.info("viewer sent invalid input: %s", exc)
                slot.put_control({"type": "error", "message": str(exc)})
                continue
            service.set_camera(camera)
            service.viewers.broadcast({"type": "camera", "camera": camera.to_json()}, exclude=slot)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        sender.cancel()
        service.viewers.leave(slot)
