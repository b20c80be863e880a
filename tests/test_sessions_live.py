"""Sessions end to end (issue 19): a real coordinator and real nodes serve two sessions with
different scenes and sizes at once; every frame of each equals ``--render-once`` of its own
scene, camera and size, and closing a session while its frames are in flight leaves the other
rendering."""

from __future__ import annotations

import io

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.conftest import SCENES, scene_path, seconds
from tests.integration_support import (
    SCENE_FILES,
    assert_matches_reference,
    fetch_frame,
    orbit_cameras,
    render_once,
    scene_bounds,
    stats,
    wait_rendering,
    wait_until,
)

pytestmark = [pytest.mark.integration, pytest.mark.gl]

SIZE = (256, 192)
SESSION_SIZE = (200, 120)


def session_frame(client: httpx.Client, session_id: str, after: int) -> np.ndarray:
    """The session's first complete frame with id >= ``after``: (h, w, 3) uint8."""
    response = client.get(f"/api/sessions/{session_id}/frame.png", params={"after": after}, timeout=seconds(120))
    response.raise_for_status()
    return np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


def test_two_sessions_with_their_own_scenes_and_sizes_each_equal_render_once(coordinator_factory, tmp_path):
    bunny, engine = scene_path(SCENE_FILES["bunny"]), scene_path(SCENE_FILES["engine"])
    coordinator = coordinator_factory("--scene", str(bunny), "--size", f"{SIZE[0]}x{SIZE[1]}", "--codec", "png",
                                      "--scenes-dir", str(SCENES), "--local-nodes", "2")
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        wait_rendering(client, 2)
        created = client.post("/api/sessions", json={"scene": f"library/{SCENE_FILES['engine']}",
                                                     "size": list(SESSION_SIZE)})
        assert created.status_code == 201, created.text
        session_id = created.json()["id"]
        wait_until(lambda: client.get(f"/api/sessions/{session_id}").json()["state"] == "ready", seconds(120),
                   "the session's scene on a node")
        engine_bounds = wait_until(lambda: client.get(f"/api/sessions/{session_id}/camera").json()["bounds"],
                                   seconds(60), "the session's scene bounds")
        for index, (mine, theirs) in enumerate(zip(orbit_cameras(scene_bounds(client), 2),
                                                   orbit_cameras(engine_bounds, 2), strict=True)):
            first = client.put("/api/camera", json=mine).raise_for_status().json()["frame"]
            session_first = client.put(f"/api/sessions/{session_id}/camera", json=theirs).json()["frame"]
            _, frame = fetch_frame(client, first)
            assert_matches_reference(frame, render_once(str(bunny), mine, SIZE, tmp_path), f"default session {index}")
            session_image = session_frame(client, session_id, session_first)
            summaries = {s["id"]: s for s in stats(client)["sessions"]}   # within the share's window of its frame
            assert session_image.shape == (SESSION_SIZE[1], SESSION_SIZE[0], 3)
            assert_matches_reference(session_image, render_once(str(engine), theirs, SESSION_SIZE, tmp_path),
                                     f"engine session {index}")
        assert summaries[session_id]["size"] == list(SESSION_SIZE) and summaries[session_id]["node_share"] > 0.0

        cameras = orbit_cameras(engine_bounds, 3)
        client.put(f"/api/sessions/{session_id}/camera", json=cameras[2])
        assert client.delete(f"/api/sessions/{session_id}").status_code == 204   # frames in flight dropped
        last = client.put("/api/camera", json=orbit_cameras(scene_bounds(client), 3)[2]).json()["frame"]
        _, frame = fetch_frame(client, last)
        assert frame.shape == (SIZE[1], SIZE[0], 3) and frame.std() > 2.0
        assert [s["id"] for s in stats(client)["sessions"]] == ["default"]
