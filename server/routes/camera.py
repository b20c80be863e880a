"""The camera: ``GET /api/camera`` and ``PUT /api/camera`` (camera JSON → first frame id using it)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict

from server.routes.deps import get_service, require_token
from server.service import RenderService
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


@router.get("/api/camera")
async def get_camera(service: RenderService = Depends(get_service)) -> dict:
    """The newest camera, the last published frame id and the scene's bounds (null until a node loaded it)."""
    return {"camera": service.camera.to_json() if service.camera else None, "frame": service.store.last_id,
            "bounds": service.bounds.tolist() if service.bounds is not None else None}


@router.put("/api/camera")
async def put_camera(body: CameraBody, service: RenderService = Depends(get_service)) -> dict:
    """Set the camera; ``frame`` is the first frame id rendered with it. NaN or degenerate → 422."""
    try:
        camera = Camera.from_json(body.model_dump(exclude_none=True))
    except CameraError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    frame = service.set_camera(camera)
    service.viewers.broadcast(CameraUpdate(camera=camera))
    return {"frame": frame}
