"""Picking (issue 35): ``GET /api/pick?x=&y=`` (and per session under ``/api/sessions/{id}``): what
the centre of a pixel of the session's frame sees."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException, Query

from server.picking import PickFailed
from server.routes.deps import get_service, get_session, require_token
from server.service import RenderService
from server.sessions import Session

router = APIRouter(tags=["pick"], dependencies=[Depends(require_token)])


@router.get("/pick")
async def pick(x: int = Query(ge=0), y: int = Query(ge=0), session: Session = Depends(get_session),
               service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """What the centre of pixel (``x``, ``y``) of the session's frame (its size, origin top left)
    sees, with its newest camera, scene state and clip: ``{"hit": true, "object", "primitive",
    "point": [x, y, z], "normal": [x, y, z], "depth"}`` or ``{"hit": false}`` for background.
    ``object`` is the object's name, ``primitive`` the triangle's number among the object's (in the
    scene's loaded order), ``point`` the world point, ``normal`` the surface's unit normal facing
    the eye (on the cap of a cut: the cutting plane's), ``depth`` the point's distance from the eye
    (scene units). A pixel outside the frame is 422, a scene not loaded yet 409, no node able to
    answer 503."""
    width, height = session.size
    if x >= width or y >= height:
        raise HTTPException(status_code=422, detail=f"pixel ({x}, {y}) is outside the {width}x{height} frame")
    try:
        return await service.picks.pick(session, x, y)
    except PickFailed as exc:
        raise HTTPException(status_code=exc.status, detail=str(exc)) from None
