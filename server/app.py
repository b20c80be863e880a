"""``create_app(settings)``: the FastAPI app, one router per resource, the service and its metrics on
``app.state``."""

from __future__ import annotations

from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from fastapi.staticfiles import StaticFiles

from server.errors import validation_error
from server.metrics import CoordinatorMetrics
from server.origins import OriginPolicy
from server.routes import (
    animation,
    annotations,
    balancer,
    camera,
    clipping,
    frames,
    health,
    meshes,
    node_ws,
    nodes,
    objects,
    picking,
    posters,
    recordings,
    scenes,
    selection,
    sessions,
    stats,
    viewer_ws,
    web,
)
from server.routes.guards import refuse_cross_site_writes, refuse_watch_writes
from server.routes.scenes import UploadChecks
from server.routes.web import WEB_DIR
from server.scene_library import SceneLibrary
from server.service import RenderService
from server.settings import Settings


def create_app(settings: Settings) -> FastAPI:
    metrics = CoordinatorMetrics()
    library = SceneLibrary(settings.scenes_dir, settings.uploads_home, settings.max_upload_mb << 20)
    service = RenderService(settings, metrics, library)
    metrics.watch(service)

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        await service.start()
        yield
        await service.stop()

    app = FastAPI(title="Tessera coordinator", version="0.1.0", lifespan=lifespan,
                  description="Sort-first parallel rendering: nodes render tiles, the coordinator composites.")
    app.add_exception_handler(RequestValidationError, validation_error)
    app.state.service = service
    app.state.metrics = metrics
    app.state.settings = settings
    app.state.origins = OriginPolicy(settings.allowed_origins)
    app.state.scenes = library
    app.state.upload_checks = UploadChecks(settings.upload_check_memory_mb)
    app.middleware("http")(refuse_watch_writes)
    app.middleware("http")(refuse_cross_site_writes)   # added last: runs first
    for module in (health, scenes, nodes, node_ws, viewer_ws, web, sessions, meshes):
        app.include_router(module.router)
    app.include_router(stats.metrics_router)
    for prefix in ("/api", "/api/sessions/{session_id}"):   # the default session, and any other
        for module in (stats, camera, objects, animation, frames, balancer, clipping, selection, picking,
                       posters, recordings, annotations):
            app.include_router(module.router, prefix=prefix)
    app.mount("/web", StaticFiles(directory=WEB_DIR), name="web")
    return app
