"""The scene's animation clock (issue 11): ``GET /api/animation`` and ``PUT /api/animation`` with
any of ``{"playing", "time", "speed"}``."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, StrictBool, StrictFloat

from server.routes.deps import get_session, require_token
from server.routes.objects import loaded_scene
from server.sessions import Session
from tessera.scene.state import SceneStateError

router = APIRouter(tags=["animation"], dependencies=[Depends(require_token)])


class AnimationBody(BaseModel):
    """``playing``: play or pause; ``time``: jump there (s, scene time); ``speed``: scene seconds
    per second (negative: backwards, at most ±1000)."""

    model_config = ConfigDict(extra="forbid")
    playing: StrictBool | None = None
    time: StrictFloat | None = None
    speed: StrictFloat | None = None


@router.get("/animation")
async def get_animation(session: Session = Depends(get_session)) -> dict[str, Any]:
    """``playing``, ``time`` (s, now), ``speed``, the span it loops over (``start``, ``end``) and the
    scene's ``animations`` (name, start, end, the objects each moves; empty: nothing to play)."""
    return loaded_scene(session).animation_json(time.monotonic())


@router.put("/animation")
async def put_animation(body: AnimationBody, session: Session = Depends(get_session)) -> dict[str, int]:
    """Play, pause, jump or change speed: ``frame`` is the first frame id that shows it. A bad value
    is 422, a scene without animations 409; either way nothing changes."""
    if not loaded_scene(session).animations:
        raise HTTPException(status_code=409, detail="the scene has no animations")
    try:
        frame = session.set_animation(body.playing, body.time, body.speed)
    except SceneStateError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return {"frame": frame}
