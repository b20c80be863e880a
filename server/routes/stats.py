"""Live statistics: ``GET /api/stats`` (JSON) and ``GET /metrics`` (Prometheus text)."""

from __future__ import annotations

from fastapi import APIRouter, Depends
from fastapi.responses import PlainTextResponse

from server.routes.deps import get_service, require_token
from server.service import RenderService

router = APIRouter(tags=["stats"])


@router.get("/api/stats", dependencies=[Depends(require_token)])
async def get_stats(service: RenderService = Depends(get_service)) -> dict:
    """Frame id, fps, size, balancer, imbalance (last and 60-frame mean), latency and every node's work."""
    return service.describe()


@router.get("/metrics", response_class=PlainTextResponse, dependencies=[Depends(require_token)])
async def metrics(service: RenderService = Depends(get_service)) -> str:
    stats = service.describe()
    lines = [
        "# TYPE tessera_frame_id gauge", f"tessera_frame_id {stats['frame']}",
        "# TYPE tessera_frames_published_total counter",
        f"tessera_frames_published_total {service.stats.frames_published}",
        "# TYPE tessera_frames_cancelled_total counter",
        f"tessera_frames_cancelled_total {stats['frames_cancelled']}",
        "# TYPE tessera_fps gauge", f"tessera_fps {stats['fps']}",
        "# TYPE tessera_imbalance gauge", f"tessera_imbalance {stats['imbalance']}",
        "# TYPE tessera_imbalance_avg gauge", f"tessera_imbalance_avg {stats['imbalance_avg']}",
        "# TYPE tessera_latency_ms gauge", f"tessera_latency_ms {stats['latency_ms']}",
        "# TYPE tessera_viewer_bytes_total counter", f"tessera_viewer_bytes_total {service.viewers.bytes_published}",
        "# TYPE tessera_nodes gauge", f"tessera_nodes {len(stats['nodes'])}",
        "# TYPE tessera_node_phase_ms gauge",
    ]
    for node in stats["nodes"]:
        for phase in ("render", "readback", "encode", "send", "busy"):
            lines.append(f'tessera_node_phase_ms{{node="{node["id"]}",phase="{phase}"}} {node[phase + "_ms"]}')
    return "\n".join(lines) + "\n"
