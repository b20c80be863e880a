"""The balancer: ``GET /api/balancer`` and ``PUT /api/balancer {"name", "params"}``, switchable live."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict

from server.routes.deps import get_service, require_token
from server.service import RenderService
from tessera.balancers import BALANCERS

router = APIRouter(tags=["balancer"], dependencies=[Depends(require_token)])


class BalancerBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    params: dict[str, Any] = {}


def describe(service: RenderService) -> dict[str, Any]:
    return {
        "name": service.balancer.name,
        "params": service.balancer.params,
        "available": sorted(BALANCERS),
        "defaults": {name: dict(cls.defaults) for name, cls in sorted(BALANCERS.items())},
    }


@router.get("/api/balancer")
async def get_balancer(service: RenderService = Depends(get_service)) -> dict[str, Any]:
    return describe(service)


@router.put("/api/balancer")
async def put_balancer(body: BalancerBody, service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """Switch technique and/or parameters from the next frame; unknown names or params → 422."""
    try:
        service.set_balancer(body.name, body.params)
    except ValueError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return describe(service)
