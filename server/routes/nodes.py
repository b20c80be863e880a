"""Render nodes: ``POST /api/nodes/calibrate`` re-measures every node's speed (seed 003 §1)."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.routes.deps import get_service, require_token
from server.service import RenderService

router = APIRouter(tags=["nodes"], dependencies=[Depends(require_token)])


@router.post("/api/nodes/calibrate")
async def calibrate(service: RenderService = Depends(get_service)) -> dict:
    """Queue a calibration render on every ready node, one node at a time; speeds appear in /api/stats."""
    return {"nodes": service.calibrate_all()}
