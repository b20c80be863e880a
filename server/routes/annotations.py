"""Annotations (issue 35): ``GET /api/annotations`` and ``PUT /api/annotations`` (and per session
under ``/api/sessions/{id}``): labels pinned to points of the scene, kept with the session (across
restarts with ``--data-dir``). The viewer draws them over the picture; nothing is re-rendered."""

from __future__ import annotations

import math
from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictStr

from server.routes.deps import get_session, require_token
from server.sessions import MAX_ANNOTATIONS, Session

router = APIRouter(tags=["annotations"], dependencies=[Depends(require_token)])

#: Longest annotation text (characters).
MAX_TEXT = 200


class AnnotationBody(BaseModel):
    """A label: ``text`` pinned to the world ``point`` [x, y, z] (a picked point, say)."""

    model_config = ConfigDict(extra="forbid")
    point: list[StrictFloat] = Field(min_length=3, max_length=3)
    text: StrictStr = Field(min_length=1, max_length=MAX_TEXT)


@router.get("/annotations")
async def get_annotations(session: Session = Depends(get_session)) -> list[dict[str, Any]]:
    """The session's annotations, ``{"point": [x, y, z], "text"}`` each, in the order they were made."""
    return session.annotations


@router.put("/annotations")
async def put_annotations(body: list[AnnotationBody], session: Session = Depends(get_session)) -> list[dict[str, Any]]:
    """Replace the session's annotations (an empty list removes them all); at most 100, each point
    finite (else 422 with the reason). Returns them."""
    if len(body) > MAX_ANNOTATIONS:
        raise HTTPException(status_code=422, detail=f"at most {MAX_ANNOTATIONS} annotations, got {len(body)}")
    for number, item in enumerate(body):
        if not all(math.isfinite(value) for value in item.point):
            raise HTTPException(status_code=422, detail=f"annotation {number}: point must be finite, got {item.point}")
    session.annotations = [item.model_dump() for item in body]
    session.service.changed_sessions = True
    session.touch()
    return session.annotations
