"""The progressive still on a real coordinator with real local nodes (issues 20, 37): at rest the
refinement frames come, each saying its sample count, the last one is the adaptive still, converged
at one of its checks, and equals ``--render-once`` with the default samples, its headers and the
stats say its samples and estimated error, nothing renders after it, and input during the
refinement cancels it at once: the next frame is the interactive one."""

from __future__ import annotations

import json
from itertools import dropwhile

import httpx
import pytest
import websockets.sync.client as ws_client

from server.settings import Settings
from tessera.scheduling.refinement import DEFAULT_STILL_SAMPLES
from tessera.scheduling.scheduler import SchedulerConfig
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
from tests.test_live_pipeline import frame_published_within

pytestmark = [pytest.mark.integration, pytest.mark.gl]

SCENE = "builtin:cluster"
SIZE = (320, 180)


@pytest.fixture
def start(coordinator_factory):
    """Start a coordinator with 2 local nodes and ``args``, settled after its first frames; returns
    it and a client of it (closed at teardown)."""
    clients: list[httpx.Client] = []

    def factory(*args: str):
        coordinator = coordinator_factory("--scene", SCENE, "--size", f"{SIZE[0]}x{SIZE[1]}", "--local-nodes", "2",
                                          *args)
        clients.append(client := httpx.Client(base_url=coordinator.url, timeout=seconds(30)))
        wait_ready_nodes(client, 2)
        wait_until(lambda: stats(client)["settled"], seconds(180), "the first frames and the still")
        return coordinator, client

    yield factory
    for client in clients:
        client.close()


def test_at_rest_the_refinement_frames_converge_to_render_once_then_nothing_renders(start, tmp_path):
    coordinator, client = start()
    plan = Settings().still_plan
    assert plan.adaptive, "the default still is adaptive"
    # settled may be seen between two stills (the second node's arrival starts a new one): settled means shown
    wait_until(lambda: (s := stats(client))["settled"] and s["still"], seconds(120), "the converged still at rest")
    camera = orbit_cameras(client.get("/api/camera").json()["bounds"], 2)[1]
    with ws_client.connect(coordinator.ws_url + "/ws/view", max_size=64 << 20) as ws:
        hello = json.loads(ws.recv(timeout=seconds(30)))
        assert hello["type"] == "hello" and hello["still_adaptive"] and hello["still_samples"] == plan.most
        joined = unpack_frame(ws.recv(timeout=seconds(30)))
        assert joined.still and joined.samples in plan.checks(), "the newest frame: the still"
        first = client.put("/api/camera", json=camera).json()["frame"]
        seen = []
        while not seen or not seen[-1].still:
            message = ws.recv(timeout=seconds(60))
            if isinstance(message, str):   # the camera, as other viewers are told
                continue
            frame = unpack_frame(message)
            if frame.frame_id >= first:
                seen.append(frame)
    # the interactive frame, then up to settle_frames more while the balancer's partition still moves
    interactive = len(seen) - len(list(dropwhile(lambda frame: frame.samples == 0 and not frame.still, seen)))
    assert seen[0].frame_id == first and 1 <= interactive <= 1 + SchedulerConfig().settle_frames, \
        f"the interactive frames: {[(frame.frame_id, frame.samples) for frame in seen]}"
    refining = [frame.samples for frame in seen[interactive:]]
    samples = refining[-1]
    assert refining == sorted(set(refining)) and samples in plan.checks() and len(refining) >= 2, \
        f"the refinement frames say their growing sample counts: {refining}"
    assert not any(frame.still for frame in seen[:-1])
    still = client.get("/api/frame.png", params={"after": first, "still": "true"}, timeout=seconds(120))
    assert still.headers["x-frame-still"] == "1" and still.headers["x-frame-samples"] == str(samples)
    estimate = float(still.headers["x-frame-estimated-psnr"])
    assert estimate >= plan.target_db or samples == plan.most, "converged: its estimate reached the target"
    assert int(still.headers["x-frame-id"]) == seen[-1].frame_id
    _, image = fetch_frame(client, seen[-1].frame_id)
    assert_matches_reference(image, render_once(SCENE, camera, SIZE, tmp_path, still_samples=DEFAULT_STILL_SAMPLES),
                             "the converged still")
    settled = wait_until(lambda: (s := stats(client))["settled"] and s, seconds(60), "the still, settled")
    assert settled["still_samples"] == {"done": samples, "wanted": plan.most, "adaptive": True,
                                        "target_db": plan.target_db, "estimated_psnr_db": estimate}
    rendered = [n["tiles_rendered"] for n in settled["nodes"]]
    assert frame_published_within(coordinator.ws_url, seconds(1.5)) is None, "nothing renders after the still"
    after = stats(client)
    assert after["coordinator_cpu"]["frames"] == settled["coordinator_cpu"]["frames"]
    assert [n["tiles_rendered"] for n in after["nodes"]] == rendered
    assert after["coordinator_cpu"]["still_ms"] > 0.0


def test_input_during_the_refinement_cancels_it_and_the_interactive_frame_comes_next(start):
    """Slow nodes (×6) keep a refinement frame in flight when the camera moves: it is dropped, the
    frame that answers the move is the interactive one, and the still that follows is the new
    camera's, refined from its first sample. (Its target out of reach, the adaptive still takes its
    most samples: a refinement long enough to be seen under way on a loaded machine.)"""
    most = 12
    _, client = start("--node-slowdowns", "6,6", "--still-samples-max", str(most), "--still-target-db", "99")
    cameras = orbit_cameras(client.get("/api/camera").json()["bounds"], 3)
    client.put("/api/camera", json=cameras[1])
    wait_until(lambda: (s := stats(client))["still_samples"]["done"] >= 1 and s["frames_in_flight"] >= 1
               and not s["still"], seconds(120), "a refinement under way")
    cancelled = stats(client)["frames_cancelled"]
    answer = client.put("/api/camera", json=cameras[2]).json()["frame"]
    moved = client.get("/api/frame.png", params={"after": answer}, timeout=seconds(120))
    assert moved.headers["x-frame-id"] == str(answer), "the move's frame was not held back"
    assert moved.headers["x-frame-still"] == "0" and moved.headers["x-frame-samples"] == "0"
    assert stats(client)["frames_cancelled"] > cancelled, "the refinement frame in flight was dropped"
    wait_s = min(seconds(120), 300)   # the slowed nodes' samples until the still converges: more than the default wait
    still = client.get("/api/frame.png", params={"after": answer, "still": "true", "timeout": wait_s},
                       timeout=wait_s + 10)
    assert still.headers["x-frame-samples"] == str(most)
    assert int(still.headers["x-frame-id"]) >= answer + most, "every sample of the new still"
