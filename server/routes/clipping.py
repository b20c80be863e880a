"""Clip planes and a section box (issue 35): ``GET /api/clip`` and ``PUT /api/clip`` (and per session
under ``/api/sessions/{id}``): what the frames cut away, from the first frame the PUT returns."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat

from server.routes.deps import get_session, require_token
from server.sessions import Session
from tessera.tools.clipping import DEFAULT_CAP_COLOR, MAX_PLANES, ClipError, ClipState

router = APIRouter(tags=["clip"], dependencies=[Depends(require_token)])


class PlaneBody(BaseModel):
    """A plane through ``point`` keeping the side its ``normal`` points to (world space)."""

    model_config = ConfigDict(extra="forbid")
    point: list[StrictFloat] = Field(min_length=3, max_length=3)
    normal: list[StrictFloat] = Field(min_length=3, max_length=3)


class BoxBody(BaseModel):
    """An axis-aligned section box keeping what is inside it (``min`` below ``max`` on every axis)."""

    model_config = ConfigDict(extra="forbid")
    min: list[StrictFloat] = Field(min_length=3, max_length=3)
    max: list[StrictFloat] = Field(min_length=3, max_length=3)


class ClipBody(BaseModel):
    """Up to 6 ``planes`` and a section ``box`` (null: none); what is kept is what all of them keep.
    ``cap``: the inside of cut surfaces is drawn flat in ``cap_color`` (sRGB, 0…1), so cut solids
    look solid. An empty body cuts nothing."""

    model_config = ConfigDict(extra="forbid")
    planes: list[PlaneBody] = Field(default_factory=list, max_length=MAX_PLANES)
    box: BoxBody | None = None
    cap: StrictBool = True
    cap_color: list[StrictFloat] = Field(default=list(DEFAULT_CAP_COLOR), min_length=3, max_length=3)


@router.get("/clip")
async def get_clip(session: Session = Depends(get_session)) -> dict[str, Any]:
    """The clip planes and section box the frames are cut by (no planes and a null box: none)."""
    return (session.frames.clip or ClipState()).to_json()


@router.put("/clip")
async def put_clip(body: ClipBody, session: Session = Depends(get_session)) -> dict[str, int]:
    """Cut the frames by these planes and box: ``frame`` is the first frame id cut so. A NaN or
    infinite number, a zero normal or an empty box is 422, and nothing changes."""
    try:
        clip = ClipState.from_json(body.model_dump())
    except ClipError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return {"frame": session.set_clip(clip)}
