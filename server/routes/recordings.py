"""Films (issue 35): ``POST /api/sessions/{id}/recordings`` renders every frame of a camera path (the
benchmarks' format) or an orbit on the cluster, as fast as the nodes allow, into an H.264 MP4;
``GET …/recordings[/{rid}]`` says how far it is, ``GET …/recordings/{rid}.mp4`` gives it,
``DELETE …/recordings/{rid}`` cancels or deletes it."""

from __future__ import annotations

import math
from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt

from server.render_jobs import DEFAULT_FILM_SAMPLES, JobRefused
from server.routes.deps import get_service, get_session, require_token
from server.routes.job_routes import add_job_routes, check_samples
from server.service import RenderService
from server.sessions import Session
from tessera.geometry import Camera, CameraError
from tessera.scheduling.render_jobs import orbit_cameras

router = APIRouter(tags=["recordings"], dependencies=[Depends(require_token)])

#: Frame rates a film may have (frames per second).
MIN_FPS, MAX_FPS = 1.0, 120.0


class PathBody(BaseModel):
    """A camera path as the benchmarks write it: ``dt_ms`` between frames, ``frames`` camera JSON each."""

    model_config = ConfigDict(extra="ignore")
    dt_ms: StrictFloat = 33.3
    frames: list[dict[str, Any]] = Field(min_length=1)


class OrbitBody(BaseModel):
    """``turns`` around the session camera's target about its up axis, in ``seconds``."""

    model_config = ConfigDict(extra="forbid")
    turns: StrictFloat = 1.0
    seconds: StrictFloat = 10.0


class RecordingBody(BaseModel):
    """``path`` or ``orbit`` (one of them); ``fps`` (default: the path's, 1000 / dt_ms, or 30);
    ``size`` [w, h] (even sides, at most ``--max-size``; default the session's, made even);
    ``samples`` per frame (1…127, default 1: the interactive frame's anti-aliasing at full detail)."""

    model_config = ConfigDict(extra="forbid")
    path: PathBody | None = None
    orbit: OrbitBody | None = None
    fps: StrictFloat | None = None
    size: list[StrictInt] | None = Field(default=None, min_length=2, max_length=2)
    samples: StrictInt = DEFAULT_FILM_SAMPLES


def cameras_of(body: RecordingBody, session: Session, fps: float) -> list[Camera]:
    """The film's cameras; 422 naming what is wrong."""
    if body.path is not None:
        cameras = []
        for number, data in enumerate(body.path.frames):
            try:
                cameras.append(Camera.from_json(data))
            except CameraError as exc:
                raise HTTPException(status_code=422, detail=f"path.frames[{number}]: {exc}") from None
        return cameras
    assert body.orbit is not None
    turns, seconds = body.orbit.turns, body.orbit.seconds
    if not (math.isfinite(turns) and 0.0 < abs(turns) <= 100.0 and math.isfinite(seconds) and seconds > 0.0):
        raise HTTPException(status_code=422, detail=f"orbit: turns must be 0 < |turns| <= 100 and seconds > 0, got "
                                                    f"{turns} and {seconds}")
    if session.camera is None:
        raise HTTPException(status_code=409, detail="no node has loaded the session's scene yet")
    return orbit_cameras(session.camera, turns, max(1, round(seconds * fps)))


@router.post("/recordings", status_code=202)
async def post_recording(body: RecordingBody, session: Session = Depends(get_session),
                         service: RenderService = Depends(get_service)) -> dict[str, str]:
    """Render a film of the session's scene as it is now (scene state, clip, selection) along a
    camera ``path`` or an ``orbit``: every frame at full detail on the cluster, not in real time,
    lower in priority than the sessions' frames; 202 ``{"id"}``. Bad input 422 with the reason
    (no or both of path and orbit, NaN cameras, odd or too large sides, too many frames), beyond
    ``--max-jobs`` 503, before the scene is loaded 409; a sort-last session's film is 409 (not
    drawn in that mode yet)."""
    if (body.path is None) == (body.orbit is None):
        raise HTTPException(status_code=422, detail="give one of path (a camera path) and orbit")
    fps = body.fps if body.fps is not None else 1000.0 / body.path.dt_ms if body.path is not None else 30.0
    if not (math.isfinite(fps) and MIN_FPS <= fps <= MAX_FPS):
        raise HTTPException(status_code=422, detail=f"fps must be {MIN_FPS:g}..{MAX_FPS:g}, got {fps}")
    largest = service.settings.max_size
    width, height = body.size if body.size is not None else (session.size[0] // 2 * 2, session.size[1] // 2 * 2)
    if not (16 <= width <= largest[0] and 16 <= height <= largest[1]) or width % 2 or height % 2:
        raise HTTPException(status_code=422, detail=f"a film's sides are even, 16x16 to {largest[0]}x{largest[1]} "
                                                    f"(--max-size), got {width}x{height}")
    check_samples(body.samples)
    cameras = cameras_of(body, session, fps)
    if len(cameras) > service.settings.max_film_frames:
        raise HTTPException(status_code=422, detail=f"{len(cameras)} frames, more than --max-film-frames "
                                                    f"{service.settings.max_film_frames}")
    try:
        job = service.jobs.start(session.id, "film", cameras, (width, height), body.samples, session.frames, fps)
    except JobRefused as exc:
        raise HTTPException(status_code=exc.status, detail=str(exc)) from None
    return {"id": job.job_id}


add_job_routes(router, "film", "mp4", "video/mp4")
