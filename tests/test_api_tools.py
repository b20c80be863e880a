"""Clip planes, the section box and the selection on a real coordinator with real local nodes
(issue 35): the still of a clipped and selected session equals ``--render-once`` with the same
clip state and highlight, and bad input is refused with a 4xx and its reason, changing nothing."""

from __future__ import annotations

import io
import json
import math

import httpx
import numpy as np
import pytest
from PIL import Image

from tests.conftest import seconds
from tests.integration_support import assert_matches_reference, render_once, stats, wait_ready_nodes, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl]

SCENE = "builtin:spheres"
SIZE = (320, 180)
CAMERA = {"eye": [0.4, 2.2, 3.6], "target": [0.0, 0.3, 0.0], "up": [0, 1, 0], "fovy_deg": 45}
#: Cuts the spheres at z = 0.1 (the half facing the camera goes) and boxes away x > 0.5.
CLIP = {"planes": [{"point": [0, 0, 0.1], "normal": [0, 0, -1]}],
        "box": {"min": [-3, -1, -3], "max": [0.5, 3, 3]}, "cap": True, "cap_color": [0.2, 0.5, 0.9]}


@pytest.fixture(scope="module")
def coordinator():
    from tests.conftest import start_coordinator
    started = start_coordinator("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2")
    try:
        with httpx.Client(base_url=started.url, timeout=seconds(60)) as client:
            wait_ready_nodes(client, 2)
            yield started, client
    finally:
        started.proc.stop()


def still_after(client: httpx.Client, frame: int, prefix: str = "/api") -> np.ndarray:
    response = client.get(f"{prefix}/frame.png", params={"after": frame, "still": "true"}, timeout=seconds(180))
    response.raise_for_status()
    return np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


def test_clipped_and_selected_still_equals_render_once(coordinator, tmp_path) -> None:
    _, client = coordinator
    client.put("/api/camera", json=CAMERA).raise_for_status()
    client.put("/api/clip", json=CLIP).raise_for_status()
    assert client.get("/api/clip").json()["planes"][0]["normal"] == [0.0, 0.0, -1.0]
    frame = client.put("/api/selection", json={"object": "sphere2"}).raise_for_status().json()["frame"]
    assert client.get("/api/selection").json() == {"object": "sphere2"}
    still = still_after(client, frame)
    samples = 0 if stats(client)["still_samples"]["adaptive"] else stats(client)["still_samples"]["wanted"]
    reference = render_once(SCENE, CAMERA, SIZE, tmp_path, still_samples=samples, clip=CLIP, highlight="sphere2")
    assert_matches_reference(still, reference, "clipped, selected still")
    plain = render_once(SCENE, CAMERA, SIZE, tmp_path, still_samples=samples)
    assert np.any(np.abs(still.astype(int) - plain).max(axis=2) > 40), "the clip and the highlight show"
    client.put("/api/clip", json={}).raise_for_status()
    frame = client.put("/api/selection", json={"object": None}).raise_for_status().json()["frame"]
    assert client.get("/api/clip").json()["box"] is None
    assert_matches_reference(still_after(client, frame), plain, "clip and selection cleared")


@pytest.mark.parametrize("body, words", [
    ({"planes": [{"point": [0, math.nan, 0], "normal": [0, 1, 0]}]}, "planes[0].point must be finite"),
    ({"planes": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]}, "non-zero length"),
    ({"planes": [{"point": [0, 0, 0], "normal": [0, 1, 0]}] * 7}, "at most 6"),
    ({"box": {"min": [1, 0, 0], "max": [0, 1, 1]}}, "below box max"),
    ({"box": {"min": [0, 0, 0], "max": [1, math.inf, 1]}}, "box.max"),
    ({"cap_color": [2, 0, 0]}, "cap_color"),
    ({"planes": [{"point": [0, 0], "normal": [0, 1, 0]}]}, "at least 3"),
    ({"boxes": []}, "extra"),
])
def test_bad_clip_is_refused_with_a_reason_and_changes_nothing(coordinator, body, words: str) -> None:
    _, client = coordinator
    before = client.get("/api/clip").json()
    response = client.put("/api/clip", content=json.dumps(body), headers={"content-type": "application/json"})
    assert response.status_code == 422, response.text
    assert words.lower() in response.text.lower()
    assert client.get("/api/clip").json() == before


def test_selection_and_clip_of_unknown_sessions_and_objects(coordinator) -> None:
    _, client = coordinator
    response = client.put("/api/selection", json={"object": "no such thing"})
    assert response.status_code == 404 and "unknown object" in response.json()["detail"]
    assert client.put("/api/sessions/nosuchsession/clip", json={}).status_code == 404
    assert client.get("/api/sessions/nosuchsession/selection").status_code == 404
    session = client.post("/api/sessions", json={"scene": SCENE}).raise_for_status().json()
    try:
        prefix = f"/api/sessions/{session['id']}"
        wait_until(lambda: client.get(f"{prefix}/objects").status_code == 200, seconds(120), "the session's scene")
        client.put(f"{prefix}/clip", json=CLIP).raise_for_status()
        assert client.get(f"{prefix}/clip").json()["box"] == CLIP["box"]
        assert client.get("/api/clip").json()["box"] is None, "another session's clip is its own"
        watch = session["watch_url"].split("session=")[1].split("&")[0]
        refused = client.put(f"/api/sessions/{watch}/clip", json={})
        assert refused.status_code == 403
    finally:
        client.delete(f"/api/sessions/{session['id']}")
