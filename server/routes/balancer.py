"""The balancer: ``GET /api/balancer`` and ``PUT /api/balancer {"name", "params"}``, switchable live."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict

from server.routes.deps import get_session, require_token
from server.sessions import Session
from tessera.balancers import BALANCERS

router = APIRouter(tags=["balancer"], dependencies=[Depends(require_token)])


class BalancerBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    name: str
    params: dict[str, Any] = {}


def describe(session: Session) -> dict[str, Any]:
    return {
        "name": session.balancer.name,
        "params": session.balancer.params,
        "available": sorted(BALANCERS),
        "defaults": {name: dict(cls.defaults) for name, cls in sorted(BALANCERS.items())},
    }


@router.get("/balancer")
async def get_balancer(session: Session = Depends(get_session)) -> dict[str, Any]:
    return describe(session)


@router.put("/balancer")
async def put_balancer(body: BalancerBody, session: Session = Depends(get_session)) -> dict[str, Any]:
    """Switch technique and/or parameters from the next frame; unknown names or params → 422."""
    try:
        session.set_balancer(body.name, body.params)
    except ValueError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None
    return describe(session)
