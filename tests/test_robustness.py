"""Bad input gets a clear error and loses nothing: misbehaving peers on real sockets against a real
coordinator that keeps serving correct frames from a real node."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest
import websockets.sync.client as ws_client
from websockets.exceptions import ConnectionClosed

from tessera.codec import Codec, encode
from tessera.geometry import Rect
from tessera.protocol import PROTOCOL_VERSION, TileHeader, pack_tile
from tests.conftest import seconds
from tests.integration_support import fetch_frame, ready_nodes, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.gl]

HELLO = {"type": "hello", "name": "rogue", "token": "", "renderer": "none", "version": PROTOCOL_VERSION,
         "capabilities": {"codecs": ["png"], "slowdown": 1.0}}


def closed_with(ws, timeout: float) -> tuple[int, str]:
    """Read until the server closes; its close code and reason."""
    try:
        while True:
            ws.recv(timeout=timeout)
    except ConnectionClosed as closed:
        assert closed.rcvd is not None, "the connection dropped without a close frame"
        return closed.rcvd.code, closed.rcvd.reason


def next_json(ws, kind: str) -> dict:
    while True:
        message = ws.recv(timeout=seconds(30))
        if isinstance(message, str) and json.loads(message)["type"] == kind:
            return json.loads(message)


@pytest.fixture
def serving(coordinator_factory):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "160x120", "--codec", "png",
                                      "--local-nodes", "1")
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        wait_until(lambda: len(ready_nodes(client)) == 1, seconds(60), "the real node")
        yield coordinator, client


def assert_still_serving(client: httpx.Client) -> None:
    assert client.get("/healthz").status_code == 200
    camera = client.get("/api/camera").json()["camera"]
    frame_after = client.put("/api/camera", json=camera).json()["frame"]
    frame_id, image = fetch_frame(client, frame_after)
    assert frame_id >= frame_after and image.std() > 1.0


def test_node_protocol_violations_close_only_that_peer(serving):
    coordinator, client = serving
    url = coordinator.ws_url + "/ws/node"
    cases = [
        ("not json", "malformed JSON"),
        (json.dumps({**HELLO, "version": 99}), "protocol version"),
        (json.dumps({"type": "tile_sent"}), "unexpected message type"),
        (b"\x00\x01binary first", "JSON hello"),
    ]
    for first, reason in cases:
        with ws_client.connect(url) as ws:
            ws.send(first)
            code, text = closed_with(ws, seconds(20))
            assert code == 1008 and reason in text, (first, code, text)
    with ws_client.connect(url) as ws:
        ws.send(json.dumps(HELLO))
        next_json(ws, "welcome")
        ws.send(b"TTIL garbage that is far too short")
        code, text = closed_with(ws, seconds(20))
        assert code == 1008 and "shorter than its header" in text
    assert_still_serving(client)


def test_wrong_token_is_refused(coordinator_factory):
    coordinator = coordinator_factory("--scene", "builtin:spheres", "--size", "64x48", "--token", "s3cret")
    with ws_client.connect(coordinator.ws_url + "/ws/node") as ws:
        ws.send(json.dumps({**HELLO, "token": "wrong"}))
        assert closed_with(ws, seconds(20)) == (4401, "wrong token")
    with ws_client.connect(coordinator.ws_url + "/ws/view?token=nope") as ws:
        assert closed_with(ws, seconds(20))[0] == 4401
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        assert client.get("/api/stats").status_code == 401
        assert client.get("/api/stats", headers={"Authorization": "Bearer s3cret"}).status_code == 200
        assert client.get("/healthz").status_code == 200


def test_wrong_size_tile_is_refused_and_the_frame_completes_from_the_others(serving):
    """A rogue node takes part in frames, then answers with a tile of the wrong size: it is cut off,
    its tiles go to the real node, and the published frame is whole and correct."""
    coordinator, client = serving
    with ws_client.connect(coordinator.ws_url + "/ws/node", max_size=64 << 20) as ws:
        ws.send(json.dumps(HELLO))
        next_json(ws, "load_scene")
        bounds = client.get("/api/camera").json()["bounds"]
        ws.send(json.dumps({"type": "scene_ready", "scene": "builtin:spheres", "triangles": 1, "meshes": 1,
                            "bounds": bounds, "load_ms": 1.0}))
        render = next_json(ws, "render")
        tile = render["tiles"][0]
        rect = Rect(*tile["rect"])
        wrong = np.zeros((rect.h + 1, rect.w, 3), dtype=np.uint8)
        header = TileHeader(render["frame"], tile["tile"], rect, Codec.PNG, 1.0, 1.0, 1.0)
        ws.send(pack_tile(header, encode(wrong, Codec.PNG)))
        code, text = closed_with(ws, seconds(20))
        assert code == 1008 and "expected" in text, text
    _, image = fetch_frame(client, render["frame"])
    assert image.shape == (120, 160, 3)
    wait_until(lambda: len(client.get("/api/stats").json()["nodes"]) == 1, seconds(20), "the rogue node to leave")
    assert_still_serving(client)


def test_invalid_camera_input_is_refused_with_reasons(serving):
    coordinator, client = serving
    for bad in ({"eye": [0, 0, float("nan")], "target": [0, 0, 0]}, {"eye": [1, 1, 1], "target": [1, 1, 1]},
                {"eye": [0, 5, 0], "target": [0, 0, 0], "up": [0, 1, 0]}, {"eye": [0, 0, 1]},
                {"eye": [0, 0, 1], "target": [0, 0, 0], "fovy_deg": 0}):
        response = client.put("/api/camera", content=json.dumps(bad, allow_nan=True),
                              headers={"content-type": "application/json"})
        assert response.status_code == 422, (bad, response.text)
        assert "camera" in response.text or "field required" in response.text.lower() or "missing" in response.text
    assert client.put("/api/balancer", json={"name": "no-such"}).status_code == 422
    assert client.put("/api/balancer", json={"name": "static", "params": {"nope": 1}}).status_code == 422
    with ws_client.connect(coordinator.ws_url + "/ws/view", max_size=64 << 20) as ws:
        ws.send(json.dumps({"type": "camera", "camera": {"eye": [0, 0, "x"], "target": [0, 0, 0]}}))
        assert "must be numbers" in next_json(ws, "error")["message"]
        ws.send("{not json")
        assert "malformed JSON" in next_json(ws, "error")["message"]
        ws.send(json.dumps({"type": "camera", "camera": client.get("/api/camera").json()["camera"]}))
    assert_still_serving(client)


def test_broken_scene_file_is_reported_and_the_coordinator_stays_up(coordinator_factory, tmp_path):
    broken = tmp_path / "broken.ply"
    broken.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99999\n\x00\x01 garbage")
    coordinator = coordinator_factory("--scene", str(broken), "--size", "64x48", "--local-nodes", "1")
    with httpx.Client(base_url=coordinator.url, timeout=seconds(30)) as client:
        node = wait_until(lambda: next((n for n in client.get("/api/stats").json()["nodes"]
                                        if n["state"] == "error"), None), seconds(60), "the node's scene error")
        assert "broken.ply" in node["scene_message"] and "\n" not in node["scene_message"]
        assert client.get("/healthz").status_code == 200
        assert client.get("/api/stats").json()["frame"] == 0
    assert "broken.ply" in coordinator.proc.output()


def test_documented_endpoints_are_served(serving):
    _, client = serving
    assert client.get("/docs").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    for path in ("/healthz", "/api/stats", "/api/camera", "/api/frame.png", "/api/balancer", "/metrics"):
        assert path in paths, path
    assert "put" in paths["/api/camera"] and "put" in paths["/api/balancer"]
    metrics = client.get("/metrics").text
    assert "tessera_fps " in metrics and 'tessera_node_phase_ms{node="1",phase="render"}' in metrics
    page = client.get("/")
    assert page.status_code == 200 and "web/viewer.js" in page.text
    assert client.get("/web/viewer.js").status_code == 200
    stats = client.get("/api/stats").json()
    for key in ("frame", "fps", "size", "balancer", "imbalance", "imbalance_avg", "latency_ms", "nodes"):
        assert key in stats, key
    for key in ("id", "name", "tiles", "render_ms", "readback_ms", "encode_ms", "send_ms", "busy_ms", "speed"):
        assert key in stats["nodes"][0], key
