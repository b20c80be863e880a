"""The scene's animation clock (issue 11): ``GET /api/animation`` and ``PUT /api/animation`` with
any of ``{"playing", "time", "speed"}``."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, StrictBool, StrictFloat

from server.routes.deps import get_service, require_token
from server.routes.objects import loaded_scene
from server.service import RenderService
from tessera.scene.state import SceneStateError

router = APIRouter(tags=["animation"], dependencies=[Depends(require_token)])


class AnimationBody(BaseModel):
    """``playing``: play or pause; ``time``: jump there (s, scene time); ``speed``: scene seconds
    per second (negative: backwards, at most ±1000)."""

    model_config = ConfigDict(extra="forbid")
    playing: StrictBool | None = None
    time: StrictFloat | None = None
    speed: StrictFloat | None = None


@router.get("/api/animation")
async def get_animation(service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """``playing``, ``time`` (s, now), ``speed``, the span it loops over (``start``, ``end``) and the
    scene's ``animations`` (name, start, end, the objects each moves; empty: nothing to play)."""
    return loaded_scene(service).animation_json(time.monotonic())


@router.put("/api/animation")
async def put_animation(body: AnimationBody, service: RenderService = Depends(get_service)) -> dict[str, int]:
    """Play, pause, jump or change speed: ``frame`` is the first frame id that shows it. A bad value
    is 422, a scene without animations 409; either way nothing changes."""
    if not loaded_scene(service).animations:
        raise HTTPException(status_code=409, detail="the scene has no animations")
    try:
        frame = service.set_animation(body.playing, body.time, body.speed)
    except SceneStateError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return {"frame": frame}
