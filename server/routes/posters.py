"""Posters (issue 35): ``POST /api/sessions/{id}/posters`` renders one picture of up to
16384×16384 at the session's camera and state on the cluster; ``GET …/posters[/{pid}]`` says how
far it is, ``GET …/posters/{pid}.png`` gives it, ``DELETE …/posters/{pid}`` cancels or deletes it."""

from __future__ import annotations

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel, ConfigDict, Field, StrictInt

from server.render_jobs import DEFAULT_POSTER_SAMPLES, JobRefused
from server.routes.deps import get_service, get_session, require_token
from server.routes.job_routes import add_job_routes, check_samples
from server.service import RenderService
from server.sessions import Session

router = APIRouter(tags=["posters"], dependencies=[Depends(require_token)])


class PosterBody(BaseModel):
    """``size`` [w, h] px (at most ``--max-poster-size``); ``samples``: jittered samples accumulated
    per pixel as the still is (1…127; default: the still's count when it is fixed, else 16)."""

    model_config = ConfigDict(extra="forbid")
    size: list[StrictInt] = Field(min_length=2, max_length=2)
    samples: StrictInt | None = None


@router.post("/posters", status_code=202)
async def post_poster(body: PosterBody, session: Session = Depends(get_session),
                      service: RenderService = Depends(get_service)) -> dict[str, str]:
    """Render a poster of the session's picture as it is now (camera, scene state, clip, selection),
    split into tiles over all nodes beside the sessions' frames: 202 ``{"id"}``. Its pixels equal
    ``python -m node --render-once --size WxH --samples N`` of the same camera and state. Beyond
    ``--max-poster-size`` or with bad samples 422, beyond ``--max-jobs`` 503, before the scene is
    loaded 409; a sort-last session's poster is 409 (not drawn in that mode yet)."""
    width, height = body.size
    largest = service.settings.max_poster_size
    if not (16 <= width <= largest[0] and 16 <= height <= largest[1]):
        raise HTTPException(status_code=422, detail=f"a poster is 16x16 to {largest[0]}x{largest[1]} px "
                                                    f"(--max-poster-size), got {width}x{height}")
    frames = session.frames
    plan = frames.demand.still_plan
    samples = body.samples if body.samples is not None else DEFAULT_POSTER_SAMPLES if plan.adaptive else plan.samples
    check_samples(samples)
    if frames.camera is None:
        raise HTTPException(status_code=409, detail="no node has loaded the session's scene yet")
    try:
        job = service.jobs.start(session.id, "poster", [frames.camera], (width, height), samples, frames)
    except JobRefused as exc:
        raise HTTPException(status_code=exc.status, detail=str(exc)) from None
    return {"id": job.job_id}


add_job_routes(router, "poster", "png", "image/png")
