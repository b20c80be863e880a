"""Live statistics: ``GET /api/stats`` (JSON; ``/api/sessions/{id}/stats`` for a session's figures)
and ``GET /metrics`` (Prometheus, by ``prometheus_client``)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import PlainTextResponse

from server.routes.deps import get_session, require_token, watching
from server.sessions import Session

router = APIRouter(tags=["stats"])
metrics_router = APIRouter(tags=["stats"])


@router.get("/stats", dependencies=[Depends(require_token)])
async def get_stats(request: Request, session: Session = Depends(get_session)) -> dict:
    """The session's frame id, fps, size, balancer, imbalance (last and 60-frame mean), latency;
    every node's work; every session's summary (``sessions``). Asked with a watch key
    (``/api/sessions/KEY/stats``): the same figures, no session's id (the keys that drive them)."""
    return session.service.describe(session, public=watching(request))


@metrics_router.get("/metrics", response_class=PlainTextResponse)
async def metrics(request: Request) -> Response:
    """Prometheus metrics (text format, or OpenMetrics when asked): histograms of frame interval,
    input → publish latency and per-tile node phases, the ``/api/stats`` figures as gauges and
    counters, and the process collector. Open, like ``/healthz``: scrapers need no token."""
    body, content_type = request.app.state.metrics.exposition(request.headers.get("accept"))
    return Response(content=body, media_type=content_type)
