"""The selected object (issue 35): ``GET /api/selection`` and ``PUT /api/selection`` (and per session
under ``/api/sessions/{id}``). The nodes draw it tinted, with its descendants, in every tile of the
frames from the one the PUT returns: the viewer selects what a click picks."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, StrictStr

from server.routes.deps import get_session, require_token
from server.routes.objects import loaded_scene
from server.sessions import Session

router = APIRouter(tags=["selection"], dependencies=[Depends(require_token)])


class SelectionBody(BaseModel):
    """``object``: the name of one of the scene's objects (``GET /api/objects``), or null for none."""

    model_config = ConfigDict(extra="forbid")
    object: StrictStr | None = None


@router.get("/selection")
async def get_selection(session: Session = Depends(get_session)) -> dict[str, str | None]:
    """The selected object's name (null: none)."""
    return {"object": session.frames.highlight}


@router.put("/selection")
async def put_selection(body: SelectionBody, session: Session = Depends(get_session)) -> dict[str, int]:
    """Select an object (null: clear the selection); ``frame`` is the first frame id that shows it.
    An unknown name is 404, a scene no node has loaded yet 409."""
    if body.object is not None and body.object not in loaded_scene(session).graph.index:
        raise HTTPException(status_code=404, detail=f"unknown object {body.object!r}")
    return {"frame": session.select(body.object)}
