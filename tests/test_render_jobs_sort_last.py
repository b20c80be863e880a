"""Posters and films of a sort-last session on a real coordinator with real local nodes (issue 35):
every piece is drawn by each node over its share with depth and merged as the live frames are,
then accumulated as the session's progressive still is. A poster at the session's size and still
samples is its converged still, pixel for pixel; posters equal ``--render-once --msaa 1`` (a
depth layer is drawn at one sample) of the same size and samples, one across two windows too; a
film plays back every frame; another session keeps its frames while a poster renders."""

from __future__ import annotations

import io

import av
import httpx
import numpy as np
import pytest
from PIL import Image

from tests.conftest import scene_path, seconds, start_coordinator
from tests.integration_support import (
    SCENE_FILES,
    assert_matches_reference,
    render_once,
    stats,
    wait_ready_nodes,
    wait_until,
)
from tests.test_render_jobs_live import assert_psnr, fetch_frame_of, finished

pytestmark = [pytest.mark.integration, pytest.mark.gl]

SCENE = str(scene_path(SCENE_FILES["bunny"]))
CAMERA = {"eye": [-0.02, 0.16, 0.2], "target": [-0.02, 0.1, 0.0], "up": [0, 1, 0], "fovy_deg": 45}
SIZE, SAMPLES = (320, 180), 3


@pytest.fixture(scope="module")
def coordinator():
    started = start_coordinator("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--mode", "sort-last",
                                "--local-nodes", "2", "--still-samples", str(SAMPLES), "--still-codec", "png",
                                "--max-jobs", "2", "--max-poster-size", "4400x2048", "--max-film-frames", "40")
    try:
        with httpx.Client(base_url=started.url, timeout=seconds(60)) as client:
            wait_ready_nodes(client, 2, timeout_s=180)
            wait_until(lambda: (p := stats(client)["partition"])["shares"] == 2 and not p["pending"], seconds(180),
                       "2 shares of one partition")
            yield started, client
    finally:
        started.proc.stop()


def poster(client: httpx.Client, size: tuple[int, int], samples: int, prefix: str = "/api") -> np.ndarray:
    job = client.post(f"{prefix}/posters", json={"size": list(size), "samples": samples})
    assert job.status_code == 202, job.text
    state = finished(client, f"{prefix}/posters/{job.json()['id']}")
    assert state["state"] == "done" and state["done"] == state["total"] > 0, state
    image = client.get(f"{prefix}/posters/{job.json()['id']}.png")
    return np.asarray(Image.open(io.BytesIO(image.content)).convert("RGB"))


def test_a_poster_at_the_session_s_size_is_its_still(coordinator) -> None:
    _, client = coordinator
    frame = client.put("/api/camera", json=CAMERA).raise_for_status().json()["frame"]
    still = client.get("/api/frame.png", params={"after": frame, "still": "true"}, timeout=seconds(180))
    still.raise_for_status()
    assert int(still.headers["x-frame-id"]) >= frame
    picture = poster(client, SIZE, SAMPLES)
    assert np.array_equal(picture, np.asarray(Image.open(io.BytesIO(still.content)).convert("RGB"))), \
        "merged and accumulated as the still is"
    assert picture.std() > 2.0, "the poster is blank"


@pytest.mark.parametrize("size, samples", [((800, 450), 3), ((2048, 2048), 1), ((4400, 64), 1)],
                         ids=["800x450", "2048x2048", "two-windows"])
def test_a_sort_last_poster_equals_render_once(coordinator, tmp_path, size, samples: int) -> None:
    _, client = coordinator
    client.put("/api/camera", json=CAMERA).raise_for_status()
    picture = poster(client, size, samples)
    reference = render_once(SCENE, CAMERA, size, tmp_path, msaa=1, still_samples=samples)
    assert_matches_reference(picture, reference, f"sort-last poster {size[0]}x{size[1]}")
    assert picture.std() > 2.0, "the poster is blank"


def test_a_sort_last_film_plays_back_every_frame(coordinator, tmp_path) -> None:
    _, client = coordinator
    client.put("/api/camera", json=CAMERA).raise_for_status()
    job = client.post("/api/recordings", json={"orbit": {"turns": 0.25, "seconds": 1.0}, "fps": 8,
                                               "size": [240, 136]})
    assert job.status_code == 202, job.text
    state = finished(client, f"/api/recordings/{job.json()['id']}")
    assert state["state"] == "done" and state["done"] == state["total"] == 8, state
    (tmp_path / "film.mp4").write_bytes(client.get(f"/api/recordings/{job.json()['id']}.mp4").content)
    with av.open(str(tmp_path / "film.mp4")) as container:
        decoded = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
    assert len(decoded) == 8 and decoded[0].shape == (136, 240, 3)
    assert_psnr(decoded[0], render_once(SCENE, CAMERA, (240, 136), tmp_path, msaa=1, still_samples=1), 35.0)


def test_other_sessions_keep_their_frames_while_a_sort_last_poster_renders(coordinator) -> None:
    _, client = coordinator
    other = client.post("/api/sessions", json={"scene": "builtin:spheres", "size": [160, 90]}).raise_for_status().json()
    prefix = f"/api/sessions/{other['id']}"
    try:
        wait_until(lambda: client.get(f"{prefix}/stats").json()["frame"] > 0, seconds(180), "the other session")
        big = client.post("/api/posters", json={"size": [2048, 2048], "samples": 8})
        assert big.status_code == 202, big.text
        before = client.get(f"{prefix}/stats").json()["frame"]
        for step in range(3):   # the other session moves while the poster renders: its frames come
            camera = {"eye": [0.5 + 0.1 * step, 1.6, 3.4], "target": [0.0, 0.35, 0.0]}
            frame = client.put(f"{prefix}/camera", json=camera).raise_for_status().json()["frame"]
            got, _ = fetch_frame_of(client, prefix, frame)
            assert got >= frame > before
        assert client.get(f"/api/posters/{big.json()['id']}").json()["state"] in ("queued", "rendering")
        cancelled = client.delete(f"/api/posters/{big.json()['id']}").raise_for_status().json()
        assert cancelled["state"] == "cancelled"
    finally:
        client.delete(f"/api/sessions/{other['id']}")
