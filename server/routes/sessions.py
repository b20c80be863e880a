"""Sessions (issue 19): ``POST /api/sessions`` opens one (with ``wall``: a display wall's, issue 22),
``GET /api/sessions`` lists them, ``GET|DELETE /api/sessions/{id}``, ``PUT /api/sessions/{id}/size``,
``PUT /api/sessions/{id}/scene`` (issue 33: another library scene, without a torn frame). Links are
built for the address the browser uses (``--root-path`` / ``X-Forwarded-Prefix`` behind a proxy).
The routes that act on a session (camera, frame.png, objects, animation, balancer, stats) are served under
``/api/sessions/{id}/…`` as under ``/api/…`` for the default session (server/app.py)."""

from __future__ import annotations

import asyncio
import time
from typing import Annotated, Any
from urllib.parse import quote

from fastapi import APIRouter, Depends, HTTPException, Request, Response
from pydantic import BaseModel, ConfigDict, Field, StrictInt

from server.origins import public_base
from server.routes.camera import CameraBody
from server.routes.deps import get_service, get_session, require_token, watching
from server.scene_library import SceneEntry, SceneLibrary, SceneRefused
from server.service import RenderService, SessionsFull
from server.sessions import Session, fit_size
from tessera.decomposition.wall_cells import WallError, WallLayout
from tessera.geometry import Camera, CameraError

#: Why a wall session's size does not change.
WALL_SIZE_FIXED = "a wall's frame is the whole wall: its size is fixed by its cells and bezels"

router = APIRouter(tags=["sessions"], dependencies=[Depends(require_token)])

Size = Annotated[list[StrictInt], Field(min_length=2, max_length=2)]


class WallBody(BaseModel):
    """A display wall: ``cols`` × ``rows`` screens of ``cell`` [w, h] px, ``bezel`` [bx, by] px apart."""

    model_config = ConfigDict(extra="forbid")
    cols: StrictInt
    rows: StrictInt
    cell: Size
    bezel: Size | None = None


class NewSession(BaseModel):
    """``scene``: a name of ``GET /api/scenes``; ``size`` [w, h] px (default ``--size``; scaled down
    to fit ``--max-size``); ``camera``: where it starts (default: framing the scene); ``wall``: a
    display wall's session, whose frame is the whole wall (no ``size`` then)."""

    model_config = ConfigDict(extra="forbid")
    scene: Annotated[str, Field(min_length=1, max_length=1024)]
    size: Size | None = None
    camera: CameraBody | None = None
    wall: WallBody | None = None


class SizeBody(BaseModel):
    model_config = ConfigDict(extra="forbid")
    size: Size


def checked_size(size: list[int], service: RenderService) -> tuple[int, int]:
    try:
        return fit_size((size[0], size[1]), service.settings.max_size)
    except ValueError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None


def checked_wall(body: WallBody, service: RenderService) -> WallLayout:
    """The wall, or 422 with what is wrong: no cells, a cell over ``--max-size``, the whole wall over
    4 × ``--max-size``'s pixels or 16384 px a side; walls need ``--mode sort-first`` (a cell's tiles
    are the nodes' own, cut at the cell edges)."""
    if service.settings.mode != "sort-first":
        raise HTTPException(status_code=422, detail=f"a wall needs --mode sort-first (this coordinator runs "
                                                    f"{service.settings.mode})")
    largest = service.settings.max_size
    try:
        return WallLayout.checked(body.cols, body.rows, body.cell, body.bezel, largest, 4 * largest[0] * largest[1])
    except WallError as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None


def public_url(request: Request) -> str:
    """The coordinator's address as the browser uses it (behind a proxy: its host, scheme and path
    prefix, ``X-Forwarded-Prefix`` or ``--root-path``), ending in ``/``."""
    headers = request.headers
    return public_base(request.url.scheme, headers.get("host"), request.app.state.settings.root_path,
                       headers.get("x-forwarded-proto"), headers.get("x-forwarded-host"),
                       headers.get("x-forwarded-prefix"))


def links(request: Request, session: Session) -> dict[str, str]:
    """The viewer page that drives the session, and the one that only watches it."""
    base = public_url(request)
    return {"viewer_url": f"{base}?session={quote(session.id)}",
            "watch_url": f"{base}?session={quote(session.watch_key)}&watch=1"}


def library_scene(request: Request, name: str, camera: CameraBody | None) -> tuple[SceneEntry, Camera | None]:
    """The library's scene ``name`` and ``camera`` as a Camera; 422 with the reason for either."""
    library: SceneLibrary = request.app.state.scenes
    try:
        return library.find(name), None if camera is None else Camera.from_json(camera.model_dump(exclude_none=True))
    except (SceneRefused, CameraError) as exc:
        raise HTTPException(status_code=422, detail=str(exc)) from None


async def scene_fetch(request: Request, entry: SceneEntry) -> tuple[str, str] | None:
    """Where nodes fetch a library file's scene from this coordinator, and its sha256 (None: built in)."""
    if entry.path is None:
        return None
    sha256 = await asyncio.to_thread(request.app.state.scenes.content_hash, entry)
    return f"/api/scenes/{quote(entry.name, safe='')}/file", sha256


@router.post("/api/sessions", status_code=201)
async def open_session(body: NewSession, request: Request,
                       service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """Open a session showing ``scene``: 201 ``{"id", "viewer_url", "watch_url", "size"}``. An unknown
    scene or a bad size or camera is 422; 503 when ``--max-sessions`` are open. Nodes load the
    scene (from the coordinator, by its content hash, when they lack the file)."""
    entry, camera = library_scene(request, body.scene, body.camera)
    if body.wall is not None and body.size is not None:
        raise HTTPException(status_code=422, detail="a wall's size is its cells' and bezels': give wall or size")
    wall = None if body.wall is None else checked_wall(body.wall, service)
    size = checked_size(body.size, service) if body.size is not None else service.settings.size
    fetch = await scene_fetch(request, entry)
    try:
        session = service.create_session(entry.name, size, camera, entry.spec, fetch, wall)
    except SessionsFull as exc:
        raise HTTPException(status_code=503, detail=str(exc)) from None
    return {"id": session.id, **links(request, session), "size": list(session.size)}


@router.get("/api/sessions")
async def list_sessions(service: RenderService = Depends(get_service)) -> list[dict[str, Any]]:
    """Every open session: ``id``, ``scene``, ``size``, ``viewers``, ``fps``, ``latency_ms``,
    ``node_share`` (its fraction of node busy time), ``state``, ``camera``, ``idle_s``."""
    now = time.monotonic()
    return [s.summary(now) for s in service.sessions.values()]


@router.get("/api/sessions/{session_id}")
async def get_session_summary(request: Request, session: Session = Depends(get_session)) -> dict[str, Any]:
    """The session's summary (as in the list) with its links; asked with its watch key, without its
    id and drive link (a watch link never leads to one)."""
    if watching(request):
        return {**session.summary(time.monotonic(), public=True), "watch_url": links(request, session)["watch_url"]}
    return {**session.summary(time.monotonic()), **links(request, session)}


@router.delete("/api/sessions/{session_id}", status_code=204)
async def close_session(session: Session = Depends(get_session),
                        service: RenderService = Depends(get_service)) -> Response:
    """Close the session: its frames are dropped and its viewers disconnected (4404). The default
    session cannot be closed (409)."""
    if session is service.default:
        raise HTTPException(status_code=409, detail="the default session cannot be closed")
    service.close_session(session)
    return Response(status_code=204)


@router.put("/api/sessions/{session_id}/size")
async def put_size(body: SizeBody, session: Session = Depends(get_session),
                   service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """Frames of ``size`` [w, h] from now on (scaled down to fit ``--max-size``): ``frame`` is the
    first frame id of that size, ``size`` the size it has. A wall's size is fixed (409)."""
    if session.wall is not None:
        raise HTTPException(status_code=409, detail=WALL_SIZE_FIXED)
    size = checked_size(body.size, service)
    return {"frame": session.resize(size), "size": list(size)}


class SceneBody(BaseModel):
    """``scene``: a name of ``GET /api/scenes``; ``camera``: where to look from (default: the
    session's camera as it is)."""

    model_config = ConfigDict(extra="forbid")
    scene: Annotated[str, Field(min_length=1, max_length=1024)]
    camera: CameraBody | None = None


@router.put("/api/sessions/{session_id}/scene")
async def put_scene(body: SceneBody, request: Request, session: Session = Depends(get_session),
                    service: RenderService = Depends(get_service)) -> dict[str, Any]:
    """Show library scene ``scene`` from now on, with the session's size, balancer and viewers (and
    its camera, unless ``camera`` is given): ``frame`` is the first frame id of the new scene, and
    until it is published viewers keep the old scene's last frame (no frame mixes the two). An
    unknown scene or a bad camera is 422; the default session shows ``--scene`` (409)."""
    if session is service.default:
        raise HTTPException(status_code=409, detail="the default session shows --scene; open a session to "
                                                    "switch scenes (POST /api/sessions)")
    entry, camera = library_scene(request, body.scene, body.camera)
    fetch = await scene_fetch(request, entry)
    if service.find_session(session.id) is not session:
        raise HTTPException(status_code=404, detail="no such session")
    return {"frame": service.switch_scene(session, entry.name, entry.spec, fetch, camera), "scene": entry.name}
