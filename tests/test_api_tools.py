"""Clip planes, the section box, the selection and picking on a real coordinator with real local
nodes (issue 35): the still of a clipped and selected session equals ``--render-once`` with the
same clip state and highlight; picks name what the pixel sees, the point within half a pixel's
footprint of geometry of known position, in sort-first and sort-last; bad input is refused with a
4xx and its reason, changing nothing."""

from __future__ import annotations

import io
import json
import math

import httpx
import numpy as np
import pytest
from PIL import Image

from tessera.geometry import Camera, view_projection
from tessera.tools.picking import pixel_ray
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


def project(point, camera: Camera, bounds, size=SIZE) -> tuple[int, int]:
    clip = view_projection(camera, size, np.asarray(bounds)) @ np.append(np.asarray(point, dtype=float), 1.0)
    return int((clip[0] / clip[3] + 1) / 2 * size[0]), int((1 - clip[1] / clip[3]) / 2 * size[1])


def check_picks(client: httpx.Client, prefix: str = "/api") -> None:
    """Picks of the spheres' centres name them; a ground pixel's point is within half a pixel's
    footprint of where its ray meets y = 0; the sky is no hit."""
    client.put(f"{prefix}/camera", json=CAMERA).raise_for_status()
    bounds = client.get(f"{prefix}/camera").json()["bounds"]
    camera = Camera.from_json(CAMERA)
    objects = {o["name"]: o for o in client.get(f"{prefix}/objects").json()}
    for name in ("sphere0", "sphere3"):
        centre = np.mean(objects[name]["bounds"], axis=0)
        x, y = project(centre, camera, bounds)
        hit = client.get(f"{prefix}/pick", params={"x": x, "y": y}).raise_for_status().json()
        assert hit["hit"] and hit["object"] == name, hit
        assert abs(np.linalg.norm(np.asarray(hit["point"]) - centre) - 0.35) < 0.01
    x, y = project([-1.5, 0.0, 1.5], camera, bounds)
    hit = client.get(f"{prefix}/pick", params={"x": x, "y": y}).json()
    assert hit["object"] == "ground" and np.allclose(hit["normal"], [0, 1, 0])
    origin, direction = pixel_ray(camera, SIZE, np.asarray(bounds), x, y)
    truth = origin + direction * (-origin[1] / direction[1])
    footprint = hit["depth"] * 2 * math.tan(math.radians(CAMERA["fovy_deg"]) / 2) / SIZE[1]
    assert np.linalg.norm(np.asarray(hit["point"]) - truth) <= 0.5 * footprint
    assert client.get(f"{prefix}/pick", params={"x": 2, "y": 2}).json() == {"hit": False}


def test_picks_name_what_the_pixel_sees(coordinator) -> None:
    _, client = coordinator
    check_picks(client)


@pytest.mark.parametrize("params, status, words", [
    ({"x": SIZE[0], "y": 0}, 422, "outside the 320x180 frame"),
    ({"x": 0, "y": SIZE[1] + 5}, 422, "outside"),
    ({"x": -1, "y": 0}, 422, "greater than or equal to 0"),
    ({"x": "nan", "y": 0}, 422, "valid integer"),
    ({"y": 0}, 422, "missing"),
])
def test_bad_picks_are_refused_with_a_reason(coordinator, params, status: int, words: str) -> None:
    _, client = coordinator
    response = client.get("/api/pick", params=params)
    assert response.status_code == status and words in response.text, response.text
    assert client.get("/api/sessions/nosuchsession/pick", params={"x": 1, "y": 1}).status_code == 404


def test_sort_last_picks_the_nearest_share(coordinator_factory) -> None:
    started = coordinator_factory("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2",
                                  "--mode", "sort-last")
    with httpx.Client(base_url=started.url, timeout=seconds(60)) as client:
        wait_ready_nodes(client, 2)
        wait_until(lambda: not stats(client)["partition"]["pending"], seconds(120), "every share loaded")
        check_picks(client)


def test_annotations_are_kept_with_the_session_and_checked(coordinator) -> None:
    _, client = coordinator
    pins = [{"point": [0.1, 0.2, 0.3], "text": "inlet"}, {"point": [1.0, 0.0, -1.0], "text": "crack, 2 mm"}]
    assert client.put("/api/annotations", json=pins).raise_for_status().json() == pins
    assert client.get("/api/annotations").json() == pins
    for body, words in (([{"point": [0, math.nan, 0], "text": "x"}], "finite"),
                        ([{"point": [0, 0, 0], "text": ""}], "at least 1 character"),
                        ([{"point": [0, 0], "text": "x"}], "at least 3"),
                        ([{"point": [0, 0, 0], "text": "x"}] * 101, "at most 100")):
        response = client.put("/api/annotations", content=json.dumps(body),
                              headers={"content-type": "application/json"})
        assert response.status_code == 422 and words in response.text, response.text
    assert client.get("/api/annotations").json() == pins, "a refused change changes nothing"
    assert client.put("/api/annotations", json=[]).json() == []
