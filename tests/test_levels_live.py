"""Levels of detail on a real coordinator with real local nodes (issue 32): the nodes build a scan's
levels in the background and say so; from then on a moving frame asks for the bound, draws fewer
triangles and equals ``--render-once --interactive --lod-error-px`` of the same camera; the still
after motion is full detail and equals ``--render-once``."""

from __future__ import annotations

import io

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.conftest import scene_path, seconds
from tests.integration_support import (
    assert_matches_reference,
    fetch_frame,
    orbit_cameras,
    render_once,
    stats,
    wait_ready_nodes,
    wait_until,
)

pytestmark = [pytest.mark.integration, pytest.mark.gl]

DRAGON = "large_scan/stanford_dragon_vrip_res2_202k.ply"
DRAGON_TRIANGLES = 202_520
SIZE = (320, 240)
BOUND = 0.5


def levels_in_use(client: httpx.Client) -> float | None:
    """The default session's levels-of-detail bound in use (None until every node holds the levels)."""
    session = next(s for s in stats(client)["sessions"] if s["id"] == "default")
    bound: float | None = session["lod_error_px"]
    return bound


def start(coordinator_factory, *args: str) -> tuple[str, httpx.Client, dict]:
    """A coordinator with 2 local nodes showing the dragon, once both hold its levels; a client
    (the caller closes it) and a camera that sees the dragon from nearby."""
    scene = str(scene_path(DRAGON))
    coordinator = coordinator_factory("--scene", scene, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2",
                                      "--codec", "png", "--lod-error-px", str(BOUND), "--lod-max-error-px", str(BOUND),
                                      *args)
    client = httpx.Client(base_url=coordinator.url, timeout=seconds(30))
    wait_ready_nodes(client, 2)
    assert wait_until(lambda: levels_in_use(client), seconds(180), "the nodes' levels of detail") == BOUND
    bounds = wait_until(lambda: client.get("/api/camera").json()["bounds"], seconds(60), "the scene's bounds")
    return scene, client, orbit_cameras(bounds, 2)[1]


def test_a_moving_frame_draws_the_levels_as_render_once_does(coordinator_factory, tmp_path):
    scene, client, camera = start(coordinator_factory, "--still-codec", "none")
    try:
        first = client.put("/api/camera", json=camera).raise_for_status().json()["frame"]
        _, moving = fetch_frame(client, first)
        drawn = sum(int(node["triangles"]) for node in stats(client)["nodes"])
        assert 0 < drawn < DRAGON_TRIANGLES, f"{drawn} triangles drawn of {DRAGON_TRIANGLES}"
        assert_matches_reference(moving, render_once(scene, camera, SIZE, tmp_path, lod_error_px=BOUND),
                                 "the moving frame at the levels of detail")
    finally:
        client.close()


def test_the_still_after_motion_is_full_detail(coordinator_factory, tmp_path):
    scene, client, camera = start(coordinator_factory)
    try:
        first = client.put("/api/camera", json=camera).raise_for_status().json()["frame"]
        response = client.get("/api/frame.png", params={"after": first, "still": "true"}, timeout=seconds(180))
        assert response.raise_for_status().headers["x-frame-still"] == "1"
        still = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
        samples = int(response.headers["x-frame-samples"])
        assert_matches_reference(still, render_once(scene, camera, SIZE, tmp_path, still_samples=samples),
                                 "the still after motion, at full detail")
    finally:
        client.close()


def test_after_a_restart_the_first_frame_is_drawn_at_the_levels_of_detail(coordinator_factory, tmp_path):
    """Levels the scene cache holds are attached before a node says 'ready': after a restart of
    coordinator and nodes (cache kept), the very first frame draws fewer triangles than the scan
    (it used to be drawn at full detail, the levels attached only after the node was ready)."""
    env = {"TESSERA_SCENE_CACHE_DIR": str(tmp_path / "cache")}
    scene = str(scene_path(DRAGON))
    args = ("--scene", scene, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2", "--codec", "png",
            "--still-codec", "none", "--lod-error-px", str(BOUND), "--lod-max-error-px", str(BOUND))
    first = coordinator_factory(*args, env=env)
    with httpx.Client(base_url=first.url, timeout=seconds(30)) as client:
        wait_until(lambda: levels_in_use(client), seconds(180), "the nodes' levels of detail")
    first.proc.stop()
    again = coordinator_factory(*args, env=env)
    with httpx.Client(base_url=again.url, timeout=seconds(30)) as client:
        drew = wait_until(lambda: [n for n in stats(client)["nodes"] if n["busy_ms"] > 0], seconds(120),
                          "the first frame after the restart, its figures rolled up")
        drawn = sum(int(node["triangles"]) for node in drew)
        assert 0 < drawn < DRAGON_TRIANGLES, f"the first frame drew {drawn} triangles of {DRAGON_TRIANGLES}"
