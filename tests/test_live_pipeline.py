"""The live pipeline on a real coordinator with real local nodes, every default but the size:
nothing renders while nothing changes, the next camera renders again, the still frame equals
``--render-once``, and each viewer's input number comes back in the frames that answer it."""

from __future__ import annotations

import json
import time

import httpx
import pytest
import websockets.sync.client as ws_client

from bench.images import psnr
from tessera.scheduling.refinement import DEFAULT_STILL_SAMPLES
from tessera.wire.protocol import unpack_frame
from tests.conftest import seconds
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

SCENE = "builtin:cluster"
SIZE = (320, 180)


@pytest.fixture
def live(coordinator_factory):
    """A coordinator with 2 local nodes and the default codecs, settled after its first frames."""
    coordinator = coordinator_factory("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2")
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        wait_ready_nodes(client, 2)
        wait_until(lambda: stats(client)["settled"], seconds(60), "the first frames and the still frame")
        yield coordinator, client


def frame_published_within(ws_url: str, duration: float) -> int | None:
    """The id of a frame a viewer connected now is sent within ``duration`` s after the newest one
    it gets on joining, or None. It blocks on the socket, so a publish ends the wait at once."""
    with ws_client.connect(ws_url + "/ws/view", max_size=64 << 20) as ws:
        assert json.loads(ws.recv(timeout=seconds(30)))["type"] == "hello"
        assert unpack_frame(ws.recv(timeout=seconds(30))).frame_id >= 1, "the newest frame, on joining"
        try:
            return unpack_frame(ws.recv(timeout=duration)).frame_id
        except TimeoutError:
            return None


def test_nothing_renders_while_nothing_changes_and_the_next_camera_renders_again(live):
    coordinator, client = live
    idle = stats(client)
    assert idle["still"] and idle["frames_in_flight"] == 0 and idle["codec"] == "jpeg"
    published = idle["coordinator_cpu"]["frames"]
    assert frame_published_within(coordinator.ws_url, seconds(1.5)) is None, \
        "a frame was published although nothing changed"
    assert stats(client)["coordinator_cpu"]["frames"] == published
    rendered = [n["tiles_rendered"] for n in stats(client)["nodes"]]
    camera = orbit_cameras(client.get("/api/camera").json()["bounds"], 1)[0]
    first = client.put("/api/camera", json=camera).json()["frame"]
    frame_id, _ = fetch_frame(client, first)
    assert frame_id >= first
    after = wait_until(lambda: settled_and_shown(client), seconds(60), "the still frame, settled")
    assert after["coordinator_cpu"]["frames"] >= published + 2, "an interactive frame, then the still frame"
    assert all(n["tiles_rendered"] > r for n, r in zip(after["nodes"], rendered, strict=True))


def settled_and_shown(client: httpx.Client) -> dict | None:
    """The stats once settled; on every look before, settled never without the still shown."""
    figures = stats(client)
    assert figures["still"] or not figures["settled"], f"settled while the still is not shown: {figures}"
    return figures if figures["settled"] else None


def test_waiting_for_a_frame_that_is_not_coming_renders_one(live):
    """The old form of GET /api/frame.png?after=K (K past the newest frame) still answers."""
    _, client = live
    newest = stats(client)["frame"]
    frame_id, image = fetch_frame(client, newest + 1)
    assert frame_id > newest and image.shape == (SIZE[1], SIZE[0], 3)


def test_the_still_frame_equals_render_once_with_the_default_codec(live, tmp_path):
    _, client = live
    camera = orbit_cameras(client.get("/api/camera").json()["bounds"], 2)[1]
    first = client.put("/api/camera", json=camera).json()["frame"]
    interactive = client.get("/api/frame.png", params={"after": first}, timeout=seconds(120))
    still = client.get("/api/frame.png", params={"after": first, "still": "true"}, timeout=seconds(120))
    assert interactive.headers["x-frame-still"] == "0" and interactive.headers["x-tile-codec"] == "jpeg"
    assert still.headers["x-frame-still"] == "1" and still.headers["x-tile-codec"] == "png"
    assert int(still.headers["x-frame-id"]) > int(interactive.headers["x-frame-id"])
    reference = render_once(SCENE, camera, SIZE, tmp_path, still_samples=DEFAULT_STILL_SAMPLES)
    _, still_image = fetch_frame(client, int(still.headers["x-frame-id"]))
    assert_matches_reference(still_image, reference, "the still frame")
    _, moving_image = fetch_frame(client, int(interactive.headers["x-frame-id"]))
    assert 25.0 < psnr(moving_image, reference) < 60.0, "the interactive frame is JPEG: close, not exact"


def test_a_frame_request_without_after_gets_the_newest_frame_the_still_at_rest(live):
    """A bare GET /api/frame.png is a picture of what is on screen now, not the oldest frame kept."""
    _, client = live
    camera = orbit_cameras(client.get("/api/camera").json()["bounds"], 3)[2]
    first = client.put("/api/camera", json=camera).json()["frame"]
    still = client.get("/api/frame.png", params={"after": first, "still": "true"}, timeout=seconds(120))
    assert still.headers["x-frame-still"] == "1" and int(still.headers["x-frame-id"]) > first
    bare = client.get("/api/frame.png", timeout=seconds(120))
    assert bare.status_code == 200 and bare.headers["x-frame-still"] == "1"
    assert bare.headers["x-frame-id"] == still.headers["x-frame-id"] == str(stats(client)["frame"])
    assert bare.content == still.content
    newest_still = client.get("/api/frame.png", params={"still": "true"}, timeout=seconds(120))
    assert newest_still.headers["x-frame-id"] == still.headers["x-frame-id"]


def test_each_viewer_gets_back_the_input_number_its_frames_answer(live):
    coordinator, client = live
    camera = client.get("/api/camera").json()["camera"]
    cameras = orbit_cameras(client.get("/api/camera").json()["bounds"], 2)
    url = coordinator.ws_url + "/ws/view"
    with ws_client.connect(url, max_size=64 << 20) as first, ws_client.connect(url, max_size=64 << 20) as second:
        for ws in (first, second):
            hello = json.loads(ws.recv(timeout=seconds(30)))
            assert hello["type"] == "hello" and hello["viewer"] > 0
        second.send(json.dumps({"type": "camera", "camera": cameras[0], "seq": 41}))
        assert answered(second, 41)
        first.send(json.dumps({"type": "camera", "camera": cameras[1], "seq": 7}))
        assert answered(first, 7)
        seen_by_second = answered(second, 41)
        assert seen_by_second, "the other viewer's frames still carry its own last input number"
        first.send(json.dumps({"type": "latency", "p50_ms": 48.5, "p90_ms": 60.0, "samples": 3, "interval_ms": 33.3}))
        first.send(json.dumps({"type": "camera", "camera": camera, "seq": -1}))
        assert "seq" in next_text(first, "error")["message"]
        first.send(json.dumps({"type": "latency", "p50_ms": "fast", "p90_ms": 1, "samples": 1, "interval_ms": 1}))
        assert "latency.p50_ms" in next_text(first, "error")["message"]
        reports = wait_until(lambda: [v["input_latency"] for v in stats(client)["viewer_stats"]
                                      if v["input_latency"]], seconds(30), "the viewer's latency report")
        assert reports == [{"p50_ms": 48.5, "p90_ms": 60.0, "samples": 3.0, "interval_ms": 33.3}]


def answered(ws, seq: int) -> bool:
    """Read frames until one answers input ``seq`` (fails on a frame answering a later one)."""
    deadline = time.monotonic() + seconds(60)
    while time.monotonic() < deadline:
        message = ws.recv(timeout=seconds(60))
        if isinstance(message, bytes):
            frame = unpack_frame(message)
            assert frame.input_seq <= seq, f"frame {frame.frame_id} answers input {frame.input_seq} > {seq}"
            if frame.input_seq == seq:
                return True
    return False


def next_text(ws, kind: str) -> dict:
    """The next control message of type ``kind`` (frames and other messages skipped)."""
    while True:
        message = ws.recv(timeout=seconds(30))
        if isinstance(message, str) and json.loads(message)["type"] == kind:
            return json.loads(message)
