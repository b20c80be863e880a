"""Live statistics: ``GET /api/stats`` (JSON) and ``GET /metrics`` (Prometheus, by ``prometheus_client``)."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request, Response
from fastapi.responses import PlainTextResponse

from server.routes.deps import get_service, require_token
from server.service import RenderService

router = APIRouter(tags=["stats"])


@router.get("/api/stats", dependencies=[Depends(require_token)])
async def get_stats(service: RenderService = Depends(get_service)) -> dict:
    """Frame id, fps, size, balancer, imbalance (last and 60-frame mean), latency and every node's work."""
    return service.describe()


@router.get("/metrics", response_class=PlainTextResponse)
async def metrics(request: Request) -> Response:
    """Prometheus metrics (text format, or OpenMetrics when asked): histograms of frame interval,
    input → publish latency and per-tile node phases, the ``/api/stats`` figures as gauges and
    counters, and the process collector. Open, like ``/healthz``: scrapers need no token."""
    body, content_type = request.app.state.metrics.exposition(request.headers.get("accept"))
    return Response(content=body, media_type=content_type)
