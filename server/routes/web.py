"""The viewer page (``GET /``); its scripts are served from ``/web``. Opened with the right
``?token=``, the page sets the token as an HttpOnly, same-site cookie: the viewer's sockets and
API calls carry it, and the viewer takes the token out of the address bar."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse

from server.origins import path_prefix
from server.routes.deps import TOKEN_COOKIE, token_ok

#: The viewer's files: web/ in the repository, server/viewer (a link to it) the package data a wheel holds.
WEB_DIR = (Path(__file__).resolve().parents[1] / "viewer").resolve()

router = APIRouter(tags=["viewer"])


@router.get("/", include_in_schema=False)
async def index(request: Request) -> FileResponse:
    """The viewer page; 404 (the same page, which says so and links to the shared session) for a
    ``?session=`` that does not exist: closed, or a wrong link."""
    key = request.query_params.get("session")
    watching = request.query_params.get("watch") in ("1", "true")
    missing = key is not None and request.app.state.service.find_session(key, watching) is None
    page = FileResponse(WEB_DIR / "index.html", status_code=404 if missing else 200,
                        headers={"Cache-Control": "no-cache"})
    token, expected = request.query_params.get("token"), request.app.state.settings.token
    if expected is not None and token is not None and token_ok(expected, token):
        secure = request.url.scheme == "https" or request.headers.get("x-forwarded-proto") == "https"
        # Only the coordinator's own paths carry it (behind a proxy: its prefix), not other sites of the host.
        path = path_prefix(request.headers.get("x-forwarded-prefix")) or request.app.state.settings.root_path
        page.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="strict", secure=secure, path=f"{path}/")
    return page
