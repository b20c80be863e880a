"""Dependencies shared by the routers: the service and the token check. They are coroutines: FastAPI
runs a plain function dependency on a worker thread (AnyIO's, which come and go with an idle
timeout), a thread hop per request for what is a dictionary look-up.

A token is presented as ``Authorization: Bearer …``, ``X-Tessera-Token``, ``?token=`` or the
``tessera_token`` cookie that the viewer page sets once it was opened with the right ``?token=``
(so the token need not stay in URLs)."""

from __future__ import annotations

import hmac

from fastapi import HTTPException, Request, WebSocket

from server.service import RenderService
from server.sessions import Session


async def get_service(request: Request) -> RenderService:
    return request.app.state.service


async def get_session(request: Request) -> Session:
    """The session a route acts on: ``/api/sessions/{session_id}/…``'s, else the default one; 404
    for an unknown id. A watch key in place of the id reads its session (``request.state.watching``
    says so; :func:`server.routes.guards.refuse_watch_writes` turns away any change made with one).
    Using a session keeps it from being closed as idle."""
    service: RenderService = request.app.state.service
    session_id = request.path_params.get("session_id")
    session = service.default if session_id is None else service.find_session(session_id)
    if session is None and session_id is not None:
        session = service.find_session(session_id, watch=True)
        request.state.watching = session is not None
    if session is None:
        raise HTTPException(status_code=404, detail="no such session (closed, or a wrong link)")
    session.touch()
    return session


def watching(request: Request) -> bool:
    """The request named its session by a watch key (:func:`get_session`)."""
    return bool(getattr(request.state, "watching", False))


TOKEN_COOKIE = "tessera_token"


def token_ok(expected: str | None, presented: str | None) -> bool:
    """Constant-time comparison (as bytes: any text a peer sends is comparable)."""
    return expected is None or (presented is not None
                                and hmac.compare_digest(expected.encode(), presented.encode(errors="replace")))


def presented_token(request: Request | WebSocket) -> str | None:
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return (request.headers.get("x-tessera-token") or request.query_params.get("token")
            or request.cookies.get(TOKEN_COOKIE))


async def require_token(request: Request) -> None:
    """REST calls under /api present the token when one is set."""
    if not token_ok(request.app.state.settings.token, presented_token(request)):
        raise HTTPException(status_code=401, detail="missing or wrong token")
