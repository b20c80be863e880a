"""Posters and films on a real coordinator with real local nodes (issue 35): a poster's pixels
equal ``--render-once`` of the same size and samples (pieces of several sizes: no seam), a film's
MP4 plays back every frame at its size (PyAV), jobs are listed, cancelled and bounded with a 4xx
and the reason, and another session keeps its frames while a job renders."""

from __future__ import annotations

import io
import json
import math

import av
import httpx
import numpy as np
import pytest
from PIL import Image

from tests.conftest import seconds, start_coordinator
from tests.integration_support import render_once, stats, wait_ready_nodes, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl]

SCENE = "builtin:spheres"
CAMERA = {"eye": [0.5, 1.6, 3.4], "target": [0.0, 0.35, 0.0], "up": [0, 1, 0], "fovy_deg": 40}
CLIP = {"planes": [{"point": [0, 0, 0.15], "normal": [0, 0, -1]}]}


@pytest.fixture(scope="module")
def coordinator():
    started = start_coordinator("--scene", SCENE, "--size", "320x180", "--local-nodes", "2", "--max-jobs", "2",
                                "--max-poster-size", "4400x2048", "--max-film-frames", "40")
    try:
        with httpx.Client(base_url=started.url, timeout=seconds(60)) as client:
            wait_ready_nodes(client, 2)
            client.put("/api/camera", json=CAMERA).raise_for_status()
            client.put("/api/clip", json=CLIP).raise_for_status()
            yield started, client
    finally:
        started.proc.stop()


def finished(client: httpx.Client, url: str, timeout_s: float = 300.0) -> dict:
    return wait_until(lambda: (s := client.get(url).raise_for_status().json())["state"] not in ("queued", "rendering")
                      and s, seconds(timeout_s), f"{url} to finish")


def test_a_poster_equals_render_once_of_its_size_and_samples(coordinator, tmp_path) -> None:
    _, client = coordinator
    job = client.post("/api/posters", json={"size": [800, 450], "samples": 3})
    assert job.status_code == 202, job.text
    poster_id = job.json()["id"]
    assert client.get(f"/api/posters/{poster_id}").json()["state"] in ("queued", "rendering", "done")
    assert any(j["id"] == poster_id for j in client.get("/api/posters").json())
    assert any(j["id"] == poster_id for j in stats(client)["jobs"])
    state = finished(client, f"/api/posters/{poster_id}")
    assert state["state"] == "done" and state["done"] == state["total"] > 0, state
    picture = np.asarray(Image.open(io.BytesIO(client.get(f"/api/posters/{poster_id}.png").content)).convert("RGB"))
    reference = render_once(SCENE, CAMERA, (800, 450), tmp_path, still_samples=3, clip=CLIP)
    assert picture.shape == (450, 800, 3)
    assert np.array_equal(picture, reference), "bit for bit render-once's"
    assert client.delete(f"/api/posters/{poster_id}").status_code == 200
    assert client.get(f"/api/posters/{poster_id}").status_code == 404


@pytest.mark.parametrize("size, samples", [((2048, 2048), 1), ((4400, 64), 2)], ids=["2048x2048", "two-windows"])
def test_a_large_poster_equals_render_once(coordinator, tmp_path, size, samples: int) -> None:
    """At 2048x2048 (one sample: the filtered frame, its pieces drawn with guard bands) and across
    two windows (4400 wide: drawn by windows, as render-once draws it at that size)."""
    _, client = coordinator
    answer = client.post("/api/posters", json={"size": list(size), "samples": samples})
    poster_id = answer.raise_for_status().json()["id"]
    assert finished(client, f"/api/posters/{poster_id}")["state"] == "done"
    picture = np.asarray(Image.open(io.BytesIO(client.get(f"/api/posters/{poster_id}.png").content)).convert("RGB"))
    reference = render_once(SCENE, CAMERA, size, tmp_path, still_samples=samples, clip=CLIP)
    assert picture.shape == reference.shape and np.array_equal(picture, reference)
    client.delete(f"/api/posters/{poster_id}")


def test_a_film_plays_back_every_frame(coordinator, tmp_path) -> None:
    _, client = coordinator
    path = {"dt_ms": 100.0, "frames": [CAMERA, {**CAMERA, "eye": [0.8, 1.5, 3.3]}, {**CAMERA, "eye": [1.1, 1.4, 3.2]}]}
    job = client.post("/api/recordings", json={"path": path, "size": [320, 180]})
    assert job.status_code == 202, job.text
    orbit = client.post("/api/recordings", json={"orbit": {"turns": 0.25, "seconds": 1.0}, "fps": 12,
                                                 "size": [240, 136], "samples": 2})
    assert orbit.status_code == 202, orbit.text
    for recording_id, frames, size in ((job.json()["id"], 3, (320, 180)), (orbit.json()["id"], 12, (240, 136))):
        state = finished(client, f"/api/recordings/{recording_id}")
        node_ms = state.pop("node_ms")
        assert state == {"id": recording_id, "kind": "film", "state": "done", "done": frames, "total": frames}, state
        assert node_ms > 0, "the node time its tiles took"
        film = client.get(f"/api/recordings/{recording_id}.mp4")
        assert film.status_code == 200 and film.headers["content-type"] == "video/mp4"
        (tmp_path / "film.mp4").write_bytes(film.content)
        with av.open(str(tmp_path / "film.mp4")) as container:
            decoded = [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]
            assert container.streams.video[0].codec_context.name == "h264"
        assert len(decoded) == frames and decoded[0].shape == (size[1], size[0], 3)
    first = decoded_first(client, job.json()["id"], tmp_path)
    reference = render_once(SCENE, CAMERA, (320, 180), tmp_path, still_samples=1, clip=CLIP)
    assert_psnr(first, reference, 35.0)


def decoded_first(client: httpx.Client, recording_id: str, tmp_path) -> np.ndarray:
    (tmp_path / "first.mp4").write_bytes(client.get(f"/api/recordings/{recording_id}.mp4").content)
    with av.open(str(tmp_path / "first.mp4")) as container:
        return next(container.decode(video=0)).to_ndarray(format="rgb24")


def assert_psnr(picture: np.ndarray, reference: np.ndarray, least_db: float) -> None:
    error = np.mean((picture.astype(float) - reference) ** 2)
    assert 10 * math.log10(255 ** 2 / max(error, 1e-12)) >= least_db


@pytest.mark.parametrize("kind, body, status, words", [
    ("posters", {"size": [8192, 16]}, 422, "--max-poster-size"),
    ("posters", {"size": [8, 8]}, 422, "16x16"),
    ("posters", {"size": [64, 64], "samples": 0}, 422, "samples must be 1..127"),
    ("posters", {"size": [64]}, 422, "at least 2"),
    ("recordings", {"size": [64, 64]}, 422, "one of path"),
    ("recordings", {"orbit": {"turns": 1, "seconds": 1}, "path": {"frames": [CAMERA]}}, 422, "one of path"),
    ("recordings", {"orbit": {"turns": 1, "seconds": 10}, "fps": 30}, 422, "--max-film-frames"),
    ("recordings", {"orbit": {"turns": math.nan, "seconds": 1}}, 422, "orbit"),
    ("recordings", {"orbit": {"turns": 1, "seconds": 1}, "size": [65, 64]}, 422, "even"),
    ("recordings", {"orbit": {"turns": 1, "seconds": 1}, "fps": 500}, 422, "fps must be"),
    ("recordings", {"path": {"frames": [{"eye": [0, 0, math.nan], "target": [0, 0, 0]}]}}, 422, "path.frames[0]"),
])
def test_bad_jobs_are_refused_with_the_reason(coordinator, kind: str, body: dict, status: int, words: str) -> None:
    _, client = coordinator
    text, headers = json.dumps(body), {"content-type": "application/json"}
    response = client.post(f"/api/{kind}", content=text, headers=headers)
    assert response.status_code == status and words in response.text, response.text
    assert client.get(f"/api/{kind}/nosuchjob").status_code == 404
    assert client.get(f"/api/{kind}/nosuchjob.{'png' if kind == 'posters' else 'mp4'}").status_code == 404
    assert client.post(f"/api/sessions/nosuchsession/{kind}", content=text, headers=headers).status_code == 404


def test_jobs_are_bounded_cancelled_and_others_keep_their_frames(coordinator) -> None:
    _, client = coordinator
    other = client.post("/api/sessions", json={"scene": "builtin:spheres", "size": [160, 90]}).raise_for_status().json()
    prefix = f"/api/sessions/{other['id']}"
    try:
        wait_until(lambda: client.get(f"{prefix}/objects").status_code == 200, seconds(120), "the other session")
        big = [client.post("/api/posters", json={"size": [2048, 2048], "samples": 8}) for _ in range(2)]
        assert all(r.status_code == 202 for r in big), [r.text for r in big]
        third = client.post("/api/posters", json={"size": [64, 64]})
        assert third.status_code == 503 and "--max-jobs" in third.text
        before = client.get(f"{prefix}/stats").json()["frame"]
        for step in range(3):   # the other session moves while the posters render: its frames come
            camera = {**CAMERA, "eye": [0.5 + 0.1 * step, 1.6, 3.4]}
            frame = client.put(f"{prefix}/camera", json=camera).raise_for_status().json()["frame"]
            got, _ = fetch_frame_of(client, prefix, frame)
            assert got >= frame > before
        assert all(client.get(f"/api/posters/{r.json()['id']}").json()["state"] in ("queued", "rendering") for r in big)
        for response in big:
            cancelled = client.delete(f"/api/posters/{response.json()['id']}").raise_for_status().json()
            assert cancelled["state"] == "cancelled" and cancelled["reason"] == "cancelled"
            answer = client.get(f"/api/posters/{response.json()['id']}.png")
            assert answer.status_code == 409 and "cancelled" in answer.text
        again = client.post("/api/posters", json={"size": [64, 64]})
        assert again.status_code == 202, again.text + coordinator[0].proc.output()[-6000:]
    finally:
        client.delete(f"/api/sessions/{other['id']}")


def fetch_frame_of(client: httpx.Client, prefix: str, after: int) -> tuple[int, np.ndarray]:
    response = client.get(f"{prefix}/frame.png", params={"after": after}, timeout=seconds(120))
    response.raise_for_status()
    return int(response.headers["x-frame-id"]), np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


def test_a_restart_fails_unfinished_jobs_with_a_reason(tmp_path) -> None:
    (tmp_path / "data").mkdir()
    args = ("--scene", SCENE, "--size", "160x90", "--local-nodes", "1", "--data-dir", str(tmp_path / "data"))
    first = start_coordinator(*args)
    try:
        with httpx.Client(base_url=first.url, timeout=seconds(60)) as client:
            wait_ready_nodes(client, 1)
            session = client.post("/api/sessions", json={"scene": SCENE}).raise_for_status().json()
            prefix = f"/api/sessions/{session['id']}"
            wait_until(lambda: client.get(f"{prefix}/objects").status_code == 200, seconds(120), "the session")
            poster = client.post(f"{prefix}/posters", json={"size": [2048, 2048], "samples": 64}).json()["id"]
            pins = [{"point": [0.0, 0.5, 0.0], "text": "kept"}]
            client.put(f"{prefix}/annotations", json=pins).raise_for_status()
    finally:
        first.proc.stop()
    second = start_coordinator(*args)
    try:
        with httpx.Client(base_url=second.url, timeout=seconds(60)) as client:
            state = client.get(f"{prefix}/posters/{poster}").raise_for_status().json()
            assert state["state"] == "error" and "restarted" in state["reason"]
            assert client.get(f"{prefix}/posters/{poster}.png").status_code == 409
            assert client.get(f"{prefix}/annotations").json() == pins, "annotations are kept with the session"
    finally:
        second.proc.stop()
