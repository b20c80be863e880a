"""The coordinator's HTTP and WebSocket API in process: ``create_app(settings)`` driven by FastAPI's
``TestClient`` (it runs the app's lifespan and speaks WebSocket), no real processes, no GL.

Validation (422s), tokens (401, close code 4401), the documented endpoints and ``/metrics``. Where
a node is needed, :class:`FakeNode` joins over ``/ws/node`` and answers every ``render`` with
flat PNG tiles, so frames are real (scheduled, published, counted) without rendering anything.
What needs real processes (a real node keeps serving correct frames) is in test_robustness.py.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from server.app import create_app
from server.settings import Settings
from tessera.geometry import Rect
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import NODE_PHASES, PROTOCOL_VERSION, TileHeader, pack_tile
from tests.conftest import seconds
from tests.integration_support import wait_until

HELLO = {"type": "hello", "name": "fake", "token": "", "renderer": "none", "version": PROTOCOL_VERSION,
         "capabilities": {"codecs": ["png"], "slowdown": 1.0}}
BOUNDS = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
#: The phase times (ms) every fake tile reports: render, readback, encode in the header, then send.
TILE_MS = {"render": 2.0, "readback": 0.5, "encode": 1.0, "send": 0.25}
pytestmark = pytest.mark.timeout(seconds(120))

SETTINGS = Settings(scene="builtin:spheres", size=(64, 48), codec=Codec.PNG)
WAIT_S = seconds(20)


@pytest.fixture
def client() -> Iterator[TestClient]:
    with TestClient(create_app(SETTINGS)) as client:
        yield client


@pytest.fixture
def token_client() -> Iterator[TestClient]:
    with TestClient(create_app(Settings(scene="builtin:spheres", size=(64, 48), token="s3cret"))) as client:
        yield client


def next_json(ws, kind: str) -> dict[str, Any]:
    """The next text message of type ``kind``, skipping the others."""
    while True:
        message = ws.receive_json()
        if message["type"] == kind:
            return message


def closed_with(ws) -> tuple[int, str]:
    """Read until the server closes; its close code and reason."""
    while True:
        message = ws.receive()
        if message["type"] == "websocket.close":
            return message["code"], message.get("reason", "")


class FakeNode:
    """A node on ``/ws/node`` that loads nothing and answers ``render`` with flat PNG tiles."""

    def __init__(self, ws) -> None:
        self.ws = ws
        self.tiles_sent = 0
        ws.send_json(HELLO)
        next_json(ws, "welcome")
        scene = next_json(ws, "load_scene")
        ws.send_json({"type": "scene_ready", "scene": scene["scene"], "triangles": 12, "meshes": 1, "chunks": 1,
                      "bounds": BOUNDS, "load_ms": 1.0})

    def answer_until(self, frame: int) -> None:
        """Answer every render message until one for ``frame`` or later was answered."""
        while True:
            render = next_json(self.ws, "render")
            self.answer(render)
            if render["frame"] >= frame:
                return

    def answer(self, render: dict[str, Any]) -> None:
        """Send every tile of ``render``, each followed by its ``tile_sent``."""
        codec = Codec.parse(render["codec"])
        for tile in render["tiles"]:
            rect = Rect(*tile["rect"])
            pixels = np.full((rect.h, rect.w, 3), 40 * (tile["tile"] % 5), dtype=np.uint8)
            header = TileHeader(render["frame"], tile["tile"], rect, codec, TILE_MS["render"],
                                TILE_MS["readback"], TILE_MS["encode"])
            self.ws.send_bytes(pack_tile(header, encode(pixels, codec)))
            self.ws.send_json({"type": "tile_sent", "frame": render["frame"], "tile": tile["tile"],
                               "send_ms": TILE_MS["send"], "stats": {}})
            self.tiles_sent += 1


def published(client: TestClient, frame: int) -> bool:
    return client.get("/api/stats").json()["frame"] >= frame


def camera_at(angle: float) -> dict[str, Any]:
    return {"eye": [4 * np.sin(angle), 1.0, 4 * np.cos(angle)], "target": [0, 0, 0], "up": [0, 1, 0]}


def metric_families(text: str) -> dict[str, Any]:
    return {family.name: family for family in text_string_to_metric_families(text)}


def histogram(families: dict[str, Any], name: str, **labels: str) -> tuple[float, float]:
    """(count, sum) of histogram ``name`` for ``labels``."""
    samples = [s for s in families[name].samples if all(s.labels.get(k) == v for k, v in labels.items())]
    count = next(s.value for s in samples if s.name == name + "_count")
    total = next(s.value for s in samples if s.name == name + "_sum")
    return count, total


# ------------------------------------------------------------------------------------------- tokens


def test_wrong_token_is_refused(token_client):
    with token_client.websocket_connect("/ws/node") as ws:
        ws.send_json({**HELLO, "token": "wrong"})
        assert closed_with(ws) == (4401, "wrong token")
    with token_client.websocket_connect("/ws/view?token=nope") as ws:
        assert closed_with(ws)[0] == 4401
    assert token_client.get("/api/stats").status_code == 401
    assert token_client.get("/api/stats", headers={"Authorization": "Bearer s3cret"}).status_code == 200
    assert token_client.get("/healthz").status_code == 200


def test_every_way_of_presenting_the_token_is_accepted(token_client):
    for path in ("/api/stats", "/api/camera", "/api/balancer"):
        assert token_client.get(path).status_code == 401, path
        assert token_client.get(path, headers={"Authorization": "Bearer nope"}).status_code == 401, path
        assert token_client.get(path, headers={"Authorization": "Bearer s3cret"}).status_code == 200, path
        assert token_client.get(path, headers={"X-Tessera-Token": "s3cret"}).status_code == 200, path
        assert token_client.get(path, params={"token": "s3cret"}).status_code == 200, path
    with token_client.websocket_connect("/ws/view?token=s3cret") as ws:
        assert ws.receive_json()["type"] == "hello"


# --------------------------------------------------------------------------------------- validation


@pytest.mark.parametrize(("first", "reason"), [
    ("not json", "malformed JSON"),
    (json.dumps({**HELLO, "version": 99}), "protocol version"),
    (json.dumps({"type": "tile_sent"}), "unexpected message type"),
    (b"\x00\x01binary first", "JSON hello"),
], ids=["not-json", "wrong-version", "not-hello", "binary-first"])
def test_a_node_that_does_not_start_with_a_hello_is_closed_with_the_reason(client, first, reason):
    with client.websocket_connect("/ws/node") as ws:
        if isinstance(first, bytes):
            ws.send_bytes(first)
        else:
            ws.send_text(first)
        code, text = closed_with(ws)
        assert code == 1008 and reason in text, (first, code, text)


def test_a_node_sending_a_broken_tile_is_closed_with_the_reason(client):
    with client.websocket_connect("/ws/node") as ws:
        ws.send_json(HELLO)
        next_json(ws, "welcome")
        ws.send_bytes(b"TTIL garbage that is far too short")
        code, text = closed_with(ws)
        assert code == 1008 and "shorter than its header" in text


def test_a_tile_outside_the_frame_is_refused_before_its_payload_is_decoded(client):
    """Fuzz finding: a 240 KB PNG of 9000 x 9000 black pixels, sent as a tile of that size by any node
    past its hello, was decoded whole (about 300 MB and 0.7 s of the event loop) before the tile
    was found not to be owed. Its rect is checked against the frame first now."""
    with client.websocket_connect("/ws/node") as ws:
        ws.send_json(HELLO)
        next_json(ws, "welcome")
        ws.send_bytes(pack_tile(TileHeader(1, 0, Rect(0, 0, 9000, 9000), Codec.PNG, 1.0, 1.0, 1.0), b"\x89PNG"))
        code, text = closed_with(ws)
        assert code == 1008 and "outside the 64x48 frame" in text, text


@pytest.mark.parametrize(("message", "reason"), [
    ({"type": "tile_sent", "frame": 1, "tile": 0, "send_ms": 1.0}, "not the tile this node just sent"),
    ({"type": "render_error", "frame": 0, "tile": 0, "message": "x"}, "without a calibrate request"),
    ({"type": "render_error", "frame": 1, "tile": 0, "message": "x"}, "does not owe"),
    ({"type": "tiles_dropped", "frame": 1, "tiles": [0]}, "was not dropped"),
], ids=["tile-sent-without-tile", "calibration-error-unasked", "render-error-not-owed", "tiles-dropped-not-dropped"])
def test_a_node_answering_what_it_was_not_asked_is_closed_with_the_reason(client, message, reason):
    """Fuzz findings (tests/test_fuzz.py): these well-formed messages about tiles the node never
    owed were ignored; each is now answered with a close and its reason."""
    with client.websocket_connect("/ws/node") as ws:
        ws.send_json(HELLO)
        next_json(ws, "welcome")
        ws.send_json(message)
        code, text = closed_with(ws)
        assert code == 1008 and reason in text, (code, text)




@pytest.mark.parametrize("bad", [
    {"eye": [0, 0, float("nan")], "target": [0, 0, 0]},
    {"eye": [1, 1, 1], "target": [1, 1, 1]},
    {"eye": [0, 5, 0], "target": [0, 0, 0], "up": [0, 1, 0]},
    {"eye": [0, 0, 1]},
    {"eye": [0, 0, 1], "target": [0, 0, 0], "fovy_deg": 0},
], ids=["nan", "eye-on-target", "up-along-view", "no-target", "zero-fovy"])
def test_invalid_camera_is_refused_with_reasons(client, bad):
    response = client.put("/api/camera", content=json.dumps(bad, allow_nan=True),
                          headers={"content-type": "application/json"})
    assert response.status_code == 422, (bad, response.text)
    assert "camera" in response.text or "field required" in response.text.lower() or "missing" in response.text


def test_invalid_balancer_is_refused(client):
    assert client.put("/api/balancer", json={"name": "no-such"}).status_code == 422
    assert client.put("/api/balancer", json={"name": "static", "params": {"nope": 1}}).status_code == 422
    huge = client.put("/api/balancer", content='{"name": "adaptive", "params": {"tau_ms": 1%s}}' % ("0" * 400),
                      headers={"content-type": "application/json"})
    assert huge.status_code == 422 and "tau_ms" in huge.text, "fuzz finding: was a 500 (int too large for a float)"



def test_a_body_of_bytes_that_are_no_utf8_gets_a_422(client):
    """Fuzz finding: a 422 that echoed such a body failed to encode it (HTTP 500, a traceback)."""
    for path in ("/api/camera", "/api/balancer"):
        response = client.put(path, content=b"\xff\xfe\x00", headers={"content-type": "text/plain"})
        assert response.status_code == 422 and "\ufffd" in response.json()["detail"][0]["input"], response.text


def test_a_frame_beyond_the_next_one_is_refused_at_once(client):
    """Fuzz finding: ``after`` past every frame on its way waited out the timeout for a 504."""
    response = client.get("/api/frame.png", params={"after": 10**30})
    assert response.status_code == 422 and "beyond the next frame" in response.text


def test_invalid_viewer_input_gets_an_error_message_and_the_socket_stays_open(client):
    with client.websocket_connect("/ws/view") as ws:
        ws.send_text(json.dumps({"type": "camera", "camera": {"eye": [0, 0, "x"], "target": [0, 0, 0]}}))
        assert "must be numbers" in next_json(ws, "error")["message"]
        ws.send_text("{not json")
        assert "malformed JSON" in next_json(ws, "error")["message"]
        ws.send_bytes(b"\x00camera")
        assert "not binary" in next_json(ws, "error")["message"]
        ws.send_text(json.dumps({"type": "camera", "camera": camera_at(0.3), "seq": -1}))
        assert "camera.seq" in next_json(ws, "error")["message"]
        ws.send_text(json.dumps({"type": "latency", "p50_ms": "fast"}))
        assert "latency.p50_ms" in next_json(ws, "error")["message"]
        ws.send_text(json.dumps({"type": "camera", "camera": camera_at(0.3), "seq": 1}))
    assert client.get("/api/camera").json()["camera"]["eye"] == pytest.approx(camera_at(0.3)["eye"])


# ------------------------------------------------------------------------------------------ endpoints


def test_documented_endpoints_are_served(client):
    with client.websocket_connect("/ws/node") as ws:
        FakeNode(ws)
        wait_until(lambda: client.get("/api/stats").json()["nodes"], WAIT_S, "the fake node", interval=0.01)
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


# -------------------------------------------------------------------------------------------- metrics


def test_metrics_after_real_frames(client):
    """Frames scheduled and published for a fake node: the histograms hold what happened, the old
    gauge names are still there, and the latency histogram's mean is ``latency_ms``."""
    with client.websocket_connect("/ws/node") as ws:
        node = FakeNode(ws)
        node.answer_until(1)
        wait_until(lambda: published(client, 1), WAIT_S, "the first frame", interval=0.01)
        for step in range(4):
            frame = client.put("/api/camera", json=camera_at(0.2 * step)).json()["frame"]
            node.answer_until(frame)
            wait_until(lambda frame=frame: published(client, frame), WAIT_S, f"frame {frame}", interval=0.01)

        def every_send_counted() -> dict[str, Any] | None:
            families = metric_families(client.get("/metrics").text)
            sends, _ = histogram(families, "tessera_node_phase_seconds", phase="send")
            return families if sends == node.tiles_sent else None

        families = wait_until(every_send_counted, WAIT_S, "every tile_sent to be counted", interval=0.01)

    stats = client.get("/api/stats").json()
    frames = stats["coordinator_cpu"]["frames"]
    assert frames >= 5
    assert next(s.value for s in families["tessera_frames_published"].samples
                if s.name == "tessera_frames_published_total") == frames
    intervals, _ = histogram(families, "tessera_frame_interval_seconds")
    assert intervals == frames - 1, "one interval per published frame after the first"
    answers, latency_sum = histogram(families, "tessera_input_to_publish_seconds")
    assert answers >= 5, "the scene's arrival and each of the 4 cameras are answered once"
    latency_ms = next(iter(families["tessera_latency_ms"].samples)).value
    assert latency_sum / answers * 1000.0 == pytest.approx(latency_ms, abs=0.01)
    for phase in NODE_PHASES:
        count, total = histogram(families, "tessera_node_phase_seconds", phase=phase)
        assert count == node.tiles_sent > 0, phase
        assert total == pytest.approx(count * TILE_MS[phase] / 1000.0), phase
    for name in ("tessera_frame_id", "tessera_fps", "tessera_imbalance", "tessera_imbalance_avg", "tessera_latency_ms",
                 "tessera_nodes", "tessera_node_phase_ms"):
        assert families[name].type == "gauge", name
    assert next(iter(families["tessera_frame_id"].samples)).value == stats["frame"]
    assert {(s.labels["node"], s.labels["phase"]) for s in families["tessera_node_phase_ms"].samples} == {
        ("1", phase) for phase in (*NODE_PHASES, "busy")}
    for name in ("tessera_frames_cancelled", "tessera_viewer_bytes"):
        assert families[name].type == "counter", name
    assert "process_cpu_seconds" in families and "process_resident_memory_bytes" in families


def test_metrics_speak_openmetrics_when_asked(client):
    response = client.get("/metrics", headers={"Accept": "application/openmetrics-text; version=1.0.0"})
    assert response.headers["content-type"].startswith("application/openmetrics-text")
    assert response.text.endswith("# EOF\n") and "tessera_frame_interval_seconds_count 0.0" in response.text
    plain = client.get("/metrics")
    assert plain.headers["content-type"].startswith("text/plain") and "# EOF" not in plain.text


def test_each_app_has_its_own_registry():
    with TestClient(create_app(SETTINGS)) as first, TestClient(create_app(SETTINGS)) as second:
        assert first.app.state.metrics.registry is not second.app.state.metrics.registry
        first.app.state.metrics.frame_published(1.0, None)
        first.app.state.metrics.frame_published(1.5, 0.1)
        count = {name: histogram(metric_families(c.get("/metrics").text), "tessera_frame_interval_seconds")[0]
                 for name, c in (("first", first), ("second", second))}
        assert count == {"first": 1, "second": 0}


def test_a_tile_a_node_cannot_render_goes_to_another_node(client):
    """One fake node reports ``render_error`` for its tile: it stays connected, the tile is rendered by
    the other node and the frame is published whole."""
    with client.websocket_connect("/ws/node") as first, client.websocket_connect("/ws/node") as second:
        failing, working = FakeNode(first), FakeNode(second)
        frame = client.put("/api/camera", json=camera_at(0.4)).json()["frame"]
        render = next_json(failing.ws, "render")
        while render["frame"] < frame:  # earlier frames hold back the new one until they complete
            failing.answer(render)
            render = next_json(failing.ws, "render")
        for tile in render["tiles"]:
            failing.ws.send_json({"type": "render_error", "frame": render["frame"], "tile": tile["tile"],
                                  "message": "out of memory"})
        working.answer_until(frame)
        working.answer_until(frame)
        wait_until(lambda: published(client, frame), WAIT_S, f"frame {frame} without the failing node's tile",
                   interval=0.01)
        nodes = client.get("/api/stats").json()["nodes"]
        assert len(nodes) == 2, "one failed tile does not disconnect a node"
