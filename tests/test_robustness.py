"""Bad input gets a clear error and loses nothing: misbehaving peers on real sockets against a real
coordinator that keeps serving correct frames from a real node. The validation itself (422s, tokens,
the documented endpoints) is checked in process in tests/test_api.py."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest
import websockets.sync.client as ws_client
from websockets.exceptions import ConnectionClosed

from tessera.geometry import Rect
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import PROTOCOL_VERSION, TileHeader, pack_tile
from tests.conftest import seconds
from tests.integration_support import fetch_frame, wait_ready_nodes, wait_until

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
        wait_ready_nodes(client, 1, timeout_s=60)
        yield coordinator, client


def assert_still_serving(client: httpx.Client) -> None:
    assert client.get("/healthz").status_code == 200
    camera = client.get("/api/camera").json()["camera"]
    frame_after = client.put("/api/camera", json=camera).json()["frame"]
    frame_id, image = fetch_frame(client, frame_after)
    assert frame_id >= frame_after and image.std() > 1.0


def test_node_protocol_violations_close_only_that_peer(serving):
    """A peer that breaks the protocol is closed (every case is in tests/test_api.py); the real node
    it shares the coordinator with keeps serving."""
    coordinator, client = serving
    url = coordinator.ws_url + "/ws/node"
    with ws_client.connect(url) as ws:
        ws.send("not json")
        code, text = closed_with(ws, seconds(20))
        assert code == 1008 and "malformed JSON" in text, (code, text)
    with ws_client.connect(url) as ws:
        ws.send(json.dumps(HELLO))
        next_json(ws, "welcome")
        ws.send(b"TTIL garbage that is far too short")
        code, text = closed_with(ws, seconds(20))
        assert code == 1008 and "shorter than its header" in text
    assert_still_serving(client)


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


def test_refused_input_leaves_the_real_node_serving(serving):
    """Input refused with reasons (every case is in tests/test_api.py) disturbs nothing: the real
    node keeps rendering correct frames."""
    coordinator, client = serving
    response = client.put("/api/camera", content=json.dumps({"eye": [0, 0, float("nan")], "target": [0, 0, 0]},
                                                          allow_nan=True), headers={"content-type": "application/json"})
    assert response.status_code == 422, response.text
    assert client.put("/api/balancer", json={"name": "no-such"}).status_code == 422
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
