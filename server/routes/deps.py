"""Dependencies shared by the routers: the service and the token check."""

from __future__ import annotations

import hmac

from fastapi import HTTPException, Request, WebSocket

from server.service import RenderService


def get_service(request: Request) -> RenderService:
    return request.app.state.service


def token_ok(expected: str | None, presented: str | None) -> bool:
    return expected is None or (presented is not None and hmac.compare_digest(expected, presented))


def presented_token(request: Request | WebSocket) -> str | None:
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return request.headers.get("x-tessera-token") or request.query_params.get("token")


def require_token(request: Request) -> None:
    """REST calls under /api present the token (Bearer header, X-Tessera-Token or ?token=) when one is set."""
    if not token_ok(request.app.state.settings.token, presented_token(request)):
        raise HTTPException(status_code=401, detail="missing or wrong token")
