"""What the posters and recordings routers share (issue 35): a job of the session by id (404 when
it is not one), its output file once done (409 with the reason before), cancelling."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import FileResponse

from server.render_jobs import RenderJob, RenderJobs
from server.routes.deps import get_service, get_session
from server.service import RenderService
from server.sessions import Session
from tessera.scheduling.refinement import MAX_STILL_SAMPLES
from tessera.scheduling.render_jobs import DONE

NOUNS = {"poster": "poster", "film": "recording"}


def job_of(jobs: RenderJobs, session: Session, job_id: str, kind: str) -> RenderJob:
    """Job ``job_id`` of ``session`` of ``kind``; 404 when there is none."""
    job = jobs.find(session.id, job_id, kind)
    if job is None:
        raise HTTPException(status_code=404, detail=f"no {NOUNS[kind]} {job_id[:40]!r} in this session (ended with "
                                                    "the session, deleted, or from before a restart)")
    return job


def output(job: RenderJob, media_type: str) -> FileResponse:
    """The job's file once it is done; 409 with what it is doing (or why it failed) before."""
    described = job.describe()
    if described["state"] != DONE or job.path is None or not job.path.exists():
        reason = described.get("reason") or f"{described['done']}/{described['total']} done"
        raise HTTPException(status_code=409, detail=f"the {NOUNS[job.kind]} is {described['state']}: {reason}")
    return FileResponse(job.path, media_type=media_type, headers={"Cache-Control": "no-store"})


def cancel(jobs: RenderJobs, job: RenderJob) -> dict[str, Any]:
    """Cancel a job under way, or delete a finished one and its file; its state after."""
    jobs.cancel(job)
    return job.describe()


def add_job_routes(router: APIRouter, kind: str, suffix: str, media_type: str) -> None:
    """The routes every kind of job has on ``router``: ``GET /{plural}`` (the session's), ``GET
    /{plural}/{id}.{suffix}`` (the output), ``GET /{plural}/{id}`` (how far), ``DELETE /{plural}/{id}``."""
    noun = NOUNS[kind]
    plural = f"/{noun}s"
    what = "frames" if kind == "film" else "the poster's piece samples"

    async def listed(session: Session = Depends(get_session),
                     service: RenderService = Depends(get_service)) -> list[dict[str, Any]]:
        return [job.describe() for job in service.jobs.of_session(session.id, kind)]

    async def result(job_id: str, session: Session = Depends(get_session),
                     service: RenderService = Depends(get_service)) -> FileResponse:
        return output(job_of(service.jobs, session, job_id, kind), media_type)

    async def state(job_id: str, session: Session = Depends(get_session),
                    service: RenderService = Depends(get_service)) -> dict[str, Any]:
        return job_of(service.jobs, session, job_id, kind).describe()

    async def delete(job_id: str, session: Session = Depends(get_session),
                     service: RenderService = Depends(get_service)) -> dict[str, Any]:
        return cancel(service.jobs, job_of(service.jobs, session, job_id, kind))

    router.add_api_route(plural, listed, methods=["GET"], name=f"list_{noun}s",
                         description=f"The session's {noun}s: ``{{\"id\", \"kind\", \"state\", \"done\", "
                                     f"\"total\", \"reason\"?}}`` each.")
    router.add_api_route(f"{plural}/{{job_id}}.{suffix}", result, methods=["GET"], name=f"{noun}_{suffix}",
                         response_class=FileResponse,
                         responses={200: {"content": {media_type: {}}}, 409: {"description": "not done (or failed)"}},
                         description=f"The {noun} ({media_type}) once done; 409 with how far it is (or why it "
                                     "failed) before.")
    router.add_api_route(f"{plural}/{{job_id}}", state, methods=["GET"], name=f"get_{noun}",
                         description=f"``{{\"state\": \"queued\"|\"rendering\"|\"done\"|\"error\"|"
                                     f"\"cancelled\", \"done\", \"total\", \"reason\"?}}``; ``done`` and "
                                     f"``total`` count {what}.")
    router.add_api_route(f"{plural}/{{job_id}}", delete, methods=["DELETE"], name=f"delete_{noun}",
                         description=f"Cancel the {noun} (its tiles still queued on the nodes are dropped), or "
                                     "delete it when done.")


def check_samples(samples: int) -> None:
    if not 1 <= samples <= MAX_STILL_SAMPLES:
        raise HTTPException(status_code=422, detail=f"samples must be 1..{MAX_STILL_SAMPLES}, got {samples}")
