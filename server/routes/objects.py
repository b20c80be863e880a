"""The scene's named objects (issue 11): ``GET /api/objects`` and ``PUT /api/objects/{name}``, a
pose that wins over the animation from the first frame it returns."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, StrictBool, StrictFloat

from server.routes.deps import get_session, require_token
from server.sessions import Session
from tessera.scene.state import ObjectPatch, SceneStateError, UnknownObjectError
from tessera.scene.timeline import SceneTimeline

router = APIRouter(tags=["objects"], dependencies=[Depends(require_token)])


class ObjectBody(BaseModel):
    """Any subset: ``translation`` [x, y, z], ``rotation`` [qx, qy, qz, qw] (normalised), ``scale``
    [sx, sy, sz] (no zero component), ``visible``; all relative to the object's parent."""

    model_config = ConfigDict(extra="forbid")
    translation: list[StrictFloat] | None = None
    rotation: list[StrictFloat] | None = None
    scale: list[StrictFloat] | None = None
    visible: StrictBool | None = None


def loaded_scene(session: Session) -> SceneTimeline:
    """The scene's timeline; 409 until a node has reported the scene's objects."""
    scene = session.scene_timeline()
    if scene is None:
        raise HTTPException(status_code=409, detail="no node has loaded the scene yet")
    return scene


@router.get("/objects")
async def get_objects(session: Session = Depends(get_session)) -> list[dict[str, Any]]:
    """Every object (glTF node; one per PLY/OBJ/STL file or built-in batch), parents first: ``name``,
    ``parent``, its local ``translation``, ``rotation``, ``scale`` and ``visible`` now (animation and
    poses applied), ``bounds`` (its geometry's world box where it is now, null without geometry) and
    ``triangles``."""
    return loaded_scene(session).objects_json(time.monotonic())


@router.put("/objects/{name:path}")
async def put_object(name: str, body: ObjectBody, session: Session = Depends(get_session)) -> dict[str, int]:
    """Pose object ``name``: ``frame`` is the first frame id that shows it. An unknown name is 404,
    a bad value 422; either way nothing changes."""
    scene = loaded_scene(session)
    try:
        scene.graph.lookup(name)
        patch = ObjectPatch.from_json(body.model_dump(exclude_none=True), name)
    except UnknownObjectError as exc:
        raise HTTPException(status_code=404, detail=str(exc)) from None
    except SceneStateError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return {"frame": session.set_objects({name: patch})}
