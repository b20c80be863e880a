"""The camera: ``GET /api/camera`` and ``PUT /api/camera`` (camera JSON → first frame id using it)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict

from server.routes.deps import get_session, require_token
from server.sessions import Session
from tessera.geometry import Camera, CameraError
from tessera.wire.messages import CameraUpdate

router = APIRouter(tags=["camera"], dependencies=[Depends(require_token)])


class CameraBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    eye: list[float]
    target: list[float]
    up: list[float] = [0.0, 1.0, 0.0]
    fovy_deg: float = 45.0
    near: float | None = None
    far: float | None = None


@router.get("/camera")
async def get_camera(session: Session = Depends(get_session)) -> dict:
    """The newest camera, the last published frame id and the scene's bounds (null until a node loaded it)."""
    return {"camera": session.camera.to_json() if session.camera else None, "frame": session.store.last_id,
            "bounds": session.bounds.tolist() if session.bounds is not None else None}


@router.put("/camera")
async def put_camera(body: CameraBody, session: Session = Depends(get_session)) -> dict:
    """Set the camera; ``frame`` is the first frame id rendered with it. NaN or degenerate → 422."""
    try:
        camera = Camera.from_json(body.model_dump(exclude_none=True))
    except CameraError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    frame = session.set_camera(camera)
    session.viewers.broadcast(CameraUpdate(camera=camera))
    return {"frame": frame}
