"""``WS /ws/view``: browsers. Each viewer gets a latest-frame slot and its own sender task;
it sends camera JSON back (with its input sequence number) and reports the input → display
latency it measured. Invalid input gets an ``error`` message, never a crash."""

from __future__ import annotations

import asyncio
import logging
import math
from typing import Any

from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from server.routes.balancer import BALANCERS
from server.routes.deps import presented_token, token_ok
from server.service import RenderService
from server.viewers import ViewerSlot
from tessera.geometry import Camera, CameraError
from tessera.protocol import ProtocolError, decode_json

router = APIRouter()
log = logging.getLogger("tessera.server")

MAX_INPUT_SEQ = 2**32 - 1
LATENCY_FIELDS = ("p50_ms", "p90_ms", "samples", "interval_ms")


async def _send(ws: WebSocket, slot: ViewerSlot) -> None:
    while True:
        message = await slot.next_message()
        if isinstance(message, str):
            await ws.send_text(message)
        else:
            await ws.send_bytes(message)


def input_seq(request: dict[str, Any]) -> int | None:
    """The optional ``seq`` of a camera message: an integer 0…2³²−1."""
    seq = request.get("seq")
    if seq is None:
        return None
    if not isinstance(seq, int) or isinstance(seq, bool) or not 0 <= seq <= MAX_INPUT_SEQ:
        raise ProtocolError(f"camera.seq must be an integer 0…{MAX_INPUT_SEQ}, got {seq!r}")
    return seq


def latency_report(request: dict[str, Any]) -> dict[str, float]:
    """A viewer's ``latency`` message: finite numbers ≥ 0 for the known fields."""
    report = {}
    for key in LATENCY_FIELDS:
        value = request.get(key)
        if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) or value < 0:
            raise ProtocolError(f"latency.{key} must be a finite number >= 0, got {value!r}")
        report[key] = round(float(value), 3)
    return report


@router.websocket("/ws/view")
async def viewer_socket(ws: WebSocket) -> None:
    service: RenderService = ws.app.state.service
    await ws.accept()
    if not token_ok(ws.app.state.settings.token, presented_token(ws)):
        await ws.close(4401, "wrong token")
        return
    slot = service.viewers.join()
    slot.put_control({
        "type": "hello", "size": list(service.size), "viewer": slot.viewer_id,
        "camera": service.camera.to_json() if service.camera else None,
        "bounds": service.bounds.tolist() if service.bounds is not None else None,
        "balancer": service.balancer.name, "balancers": sorted(BALANCERS), "frame": service.store.last_id,
    })
    if service.store.latest is not None:
        slot.put_frame(service.store.latest.message_for(slot.viewer_id))
    sender = asyncio.create_task(_send(ws, slot))
    try:
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            try:
                request = decode_json(message.get("text") or "", ["camera", "latency"])
                if request["type"] == "latency":
                    slot.latency = latency_report(request)
                    continue
                seq = input_seq(request)
                camera = Camera.from_json(request.get("camera"))
            except (ProtocolError, CameraError) as exc:
                log.info("viewer sent invalid input: %s", exc)
                slot.put_control({"type": "error", "message": str(exc)})
                continue
            service.set_camera(camera, slot.viewer_id, seq)
            service.viewers.broadcast({"type": "camera", "camera": camera.to_json()}, exclude=slot)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        sender.cancel()
        service.viewers.leave(slot)
        service.viewer_left(slot.viewer_id)
