"""Sessions over the API (issue 19), in process with fake nodes: open, list, close, resize; frames
of each session have its own size; a watcher cannot steer; bad input is refused with the reason."""

from __future__ import annotations

import dataclasses
import io
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from server.app import create_app
from server.calibration import AGREEING
from server.settings import Settings
from tessera.geometry import Rect
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import TileHeader, pack_tile, state_tag, unpack_frame
from tests.conftest import seconds
from tests.integration_support import wait_until
from tests.test_api import BOUNDS, HELLO, closed_with, next_json

pytestmark = pytest.mark.timeout(seconds(120))
SETTINGS = Settings(scene="builtin:spheres", size=(64, 48), codec=Codec.PNG, still_codec=None, max_sessions=3,
                    max_size=(200, 100))


class SceneNode:
    """A fake node over ``/ws/node`` that holds every scene it is told to load and answers each
    render with flat tiles whose grey level says which scene they are of."""

    def __init__(self, ws, hello: dict[str, Any] = HELLO, triangles: dict[str, int] | None = None,
                 points: dict[str, int] | None = None) -> None:
        self.ws = ws
        self.triangles = triangles or {}   # what it says it holds of a scene (12 unless named)
        self.points = points or {}         # the scenes it says are point clouds, and their points
        self.scenes: list[str] = []
        self.calibrations = 0
        ws.send_json(hello)
        next_json(ws, "welcome")

    def serve(self, until) -> list[dict[str, Any]]:
        """Handle messages until ``until(render)`` is true of an answered render; the renders."""
        renders = []
        while True:
            render = self.handle(self.ws.receive_json())
            if render is not None:
                renders.append(render)
                if until(render):
                    return renders

    def serve_until_calibrated(self, count: int) -> None:
        """Handle messages until ``count`` calibrations were answered."""
        while self.calibrations < count:
            self.handle(self.ws.receive_json())

    def handle(self, message: dict[str, Any]) -> dict[str, Any] | None:
        """Answer ``message``; the render it was, if one."""
        if message["type"] == "load_scene":
            self.scenes.append(message["scene"])
            points = {"points": self.points[message["scene"]]} if message["scene"] in self.points else {}
            self.ws.send_json({"type": "scene_ready", "scene": message["scene"], "scene_mb": 1.0,
                               "triangles": self.triangles.get(message["scene"], 12),
                               "bounds": BOUNDS, "objects": [{"name": "car", "bounds": BOUNDS}], **points})
        elif message["type"] == "calibrate":
            self.calibrations += 1
            self.ws.send_json({"type": "calibration", "ms": 5.0})
        elif message["type"] == "render":
            self.answer(message)
            return message
        return None

    def answer(self, render: dict[str, Any]) -> None:
        level = 40 * (self.scenes.index(render["scene"]) + 1)
        for tile in render["tiles"]:
            rect = Rect(*tile["rect"])
            header = TileHeader(render["frame"], tile["tile"], rect, Codec.PNG, 1.0, 0.0, 0.0,
                                state=state_tag((render.get("state") or {}).get("version")))
            self.ws.send_bytes(pack_tile(header, encode(np.full((rect.h, rect.w, 3), level, np.uint8), Codec.PNG)))
            self.ws.send_json({"type": "tile_sent", "frame": render["frame"], "tile": tile["tile"], "send_ms": 0.1,
                               "stats": {}})


@pytest.fixture
def client() -> Iterator[TestClient]:
    with TestClient(create_app(SETTINGS)) as client:
        yield client


def frame_png(client: TestClient, path: str, after: int) -> np.ndarray:
    response = client.get(path, params={"after": after, "timeout": seconds(20)})
    assert response.status_code == 200, response.text
    return np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))


def test_a_session_has_unguessable_keys_and_its_own_scene_and_size(client):
    created = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [80, 40]})
    assert created.status_code == 201, created.text
    body = created.json()
    session_id, watch_key = body["id"], body["watch_url"].split("session=")[1].split("&")[0]
    assert len(session_id) >= 22 and len(watch_key) >= 22, "128 random bits each, base64url"
    assert session_id not in body["watch_url"] and body["viewer_url"].endswith(f"?session={session_id}")
    assert body["size"] == [80, 40]
    listed = {s["id"]: s for s in client.get("/api/sessions").json()}
    assert listed[session_id]["scene"] == "builtin:cluster" and listed[session_id]["size"] == [80, 40]
    assert listed["default"]["size"] == [64, 48]
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws)
        first = client.put(f"/api/sessions/{session_id}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first.json()["frame"])
        assert node.scenes == ["builtin:cluster"], "the default's scene once the session's first frame is out"
        session_frame = frame_png(client, f"/api/sessions/{session_id}/frame.png", first.json()["frame"])
        assert session_frame.shape == (40, 80, 3) and (session_frame == 40).all(), "its tiles, its size"
        default_first = client.put("/api/camera", json={"eye": [0, 0, 6], "target": [0, 0, 0]}).json()["frame"]
        node.serve(lambda render: render["scene"] == "builtin:spheres" and render["frame"] >= default_first)
        assert node.scenes == ["builtin:cluster", "builtin:spheres"], "every session's scene, the default's last"
        default_frame = frame_png(client, "/api/frame.png", default_first)
        assert default_frame.shape == (48, 64, 3) and (default_frame == 80).all(), "never the other session's tiles"
        stats = client.get(f"/api/sessions/{session_id}/stats").json()
        assert stats["size"] == [80, 40] and stats["session"] == session_id
        assert {s["id"] for s in client.get("/api/stats").json()["sessions"]} == {"default", session_id}


def test_a_node_is_calibrated_on_the_default_scene_and_not_again_for_another_sessions_scene(client):
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws, {**HELLO, "capabilities": {**HELLO["capabilities"], "calibrate": True}})
        default_first = client.put("/api/camera", json={"eye": [0, 0, 6], "target": [0, 0, 0]}).json()["frame"]
        node.serve(lambda render: render["scene"] == "builtin:spheres" and render["frame"] >= default_first)
        node.serve_until_calibrated(AGREEING)   # measured once the frames are drawn, until its times agree
        session_id = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()["id"]
        first = client.put(f"/api/sessions/{session_id}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first.json()["frame"])
        default_next = client.put("/api/camera", json={"eye": [0, 0, 7], "target": [0, 0, 0]}).json()["frame"]
        node.serve(lambda render: render["scene"] == "builtin:spheres" and render["frame"] >= default_next)
        assert node.scenes == ["builtin:spheres", "builtin:cluster"]
        assert node.calibrations == AGREEING, "another session's scene is not measured"
        assert wait_until(lambda: [n["calibration_ms"] for n in client.get("/api/stats").json()["nodes"]] == [5.0],
                          seconds(10), "the calibration in the stats")


def test_a_node_may_owe_a_tile_for_the_largest_scene_a_session_shows_on_it_not_one_closed(client):
    """A node that holds 30M triangles of a session's scene may take a minute over a tile; once
    that session is closed, its tiles are timed for the scenes still shown (12 triangles)."""
    session_id = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()["id"]
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws, triangles={"builtin:cluster": 30_000_000})
        first = client.put(f"/api/sessions/{session_id}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first.json()["frame"])
        service = client.app.state.service
        (held,) = service.scheduler.nodes.values()
        (link,) = service.nodes.values()
        assert service.scheduler.table.allowed_s(held, 5.0) == 60.0
        link.scene_mb["mesh:g:0001"] = 3.0   # a simulation's step the node held, superseded since
        assert client.delete(f"/api/sessions/{session_id}").status_code == 204
        while "builtin:spheres" not in node.scenes:   # the coordinator's own scene, told once the session closed
            node.handle(ws.receive_json())
        wait_until(lambda: held.triangles == 12, seconds(10), "the coordinator's own scene held")
        assert service.scheduler.table.allowed_s(held, 5.0) == 5.0
        assert set(link.scene_triangles) == {"builtin:spheres"}, "a scene no session shows is forgotten"
        assert set(link.scene_mb) == {"builtin:spheres", "builtin:cluster"}, \
            "a mesh step no session shows is forgotten; a library scene the node still holds is not"


def test_a_node_may_owe_a_tile_of_a_point_cloud_for_its_points(client):
    """A point counts as a triangle: a node holding a 30M-point cloud may take a minute over a tile
    (a still's sample of every point in view takes tens of seconds on loaded llvmpipe nodes)."""
    session_id = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()["id"]
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws, triangles={"builtin:cluster": 0}, points={"builtin:cluster": 30_000_000})
        first = client.put(f"/api/sessions/{session_id}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first.json()["frame"])
        service = client.app.state.service
        (held,) = service.scheduler.nodes.values()
        assert service.scheduler.table.allowed_s(held, 5.0) == 60.0


def test_a_watcher_gets_frames_but_cannot_steer_and_a_closed_session_drops_its_viewers(client):
    body = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [32, 16]}).json()
    watch = body["watch_url"].split("?")[1]
    with client.websocket_connect("/ws/node") as node_ws, client.websocket_connect(f"/ws/view?{watch}") as viewer:
        node = SceneNode(node_ws)
        hello = next_json(viewer, "hello")
        assert hello["size"] == [32, 16]
        viewer.send_json({"type": "camera", "camera": {"eye": [0, 0, 5], "target": [0, 0, 0]}, "seq": 1})
        assert "cannot steer" in next_json(viewer, "error")["message"]
        first = client.put(f"/api/sessions/{body['id']}/camera", json={"eye": [1, 0, 5], "target": [0, 0, 0]})
        node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first.json()["frame"])
        while True:
            message = viewer.receive()
            if message.get("bytes"):
                assert unpack_frame(message["bytes"]).size == (32, 16)
                break
        assert client.delete(f"/api/sessions/{body['id']}").status_code == 204
        assert closed_with(viewer)[0] == 4404
    assert client.get(f"/api/sessions/{body['id']}").status_code == 404
    with client.websocket_connect(f"/ws/view?session={body['id']}") as gone:
        assert closed_with(gone) == (4404, "no such session (closed, or a wrong link)")


def test_a_drive_link_cannot_be_made_from_a_watch_key(client):
    body = client.post("/api/sessions", json={"scene": "builtin:spheres"}).json()
    watch_key = body["watch_url"].split("session=")[1].split("&")[0]
    watched = client.get(f"/api/sessions/{watch_key}").json()
    assert "id" not in watched and "viewer_url" not in watched and body["id"] not in str(watched)
    with client.websocket_connect(f"/ws/view?session={watch_key}") as ws:
        assert closed_with(ws)[0] == 4404


def test_resizing_a_session_changes_its_frames_and_sizes_are_fitted_to_the_largest(client):
    body = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [400, 100]}).json()
    assert body["size"] == [200, 50], "scaled down to --max-size 200x100, aspect kept"
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws)
        resized = client.put(f"/api/sessions/{body['id']}/size", json={"size": [60, 30]})
        assert resized.status_code == 200 and resized.json()["size"] == [60, 30]
        client.put(f"/api/sessions/{body['id']}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        renders = node.serve(lambda render: render["scene"] == "builtin:cluster")
        assert [r["size"] for r in renders if r["scene"] == "builtin:cluster"] == [[60, 30]]
        frame = frame_png(client, f"/api/sessions/{body['id']}/frame.png", resized.json()["frame"])
        assert frame.shape == (30, 60, 3)


def test_bad_sessions_are_refused_with_the_reason(client):
    unknown = client.post("/api/sessions", json={"scene": "library/nope.glb"})
    assert unknown.status_code == 422 and "nope.glb" in unknown.text
    assert client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [0, 10]}).status_code == 422
    assert client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [10]}).status_code == 422
    nan_camera = {"scene": "builtin:cluster", "camera": {"eye": [0, 0, "NaN"], "target": [0, 0, 0]}}
    assert client.post("/api/sessions", json=nan_camera).status_code == 422
    assert client.delete("/api/sessions/default").status_code == 409
    assert client.get("/api/sessions/nope/camera").status_code == 404
    for _ in range(2):
        assert client.post("/api/sessions", json={"scene": "builtin:spheres"}).status_code == 201
    full = client.post("/api/sessions", json={"scene": "builtin:spheres"})
    assert full.status_code == 503 and "--max-sessions" in full.text


def test_metrics_label_sessions_by_number_never_by_their_drive_key(client):
    body = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()
    text = client.get("/metrics").text
    assert 'tessera_session_viewers{session="default"} 0.0' in text
    assert 'tessera_session_node_share{session="1"}' in text
    assert body["id"] not in text and "tessera_session_fps" in text


def test_a_sessions_frames_follow_its_drivers_window_and_the_default_session_keeps_its_size(client):
    body = client.post("/api/sessions", json={"scene": "builtin:cluster", "size": [32, 16]}).json()
    watch = body["watch_url"].split("?")[1]
    with client.websocket_connect("/ws/node") as node_ws, \
            client.websocket_connect(f"/ws/view?session={body['id']}") as driver, \
            client.websocket_connect(f"/ws/view?{watch}") as watcher, \
            client.websocket_connect("/ws/view") as default_viewer:
        node = SceneNode(node_ws)
        for ws in (driver, watcher, default_viewer):
            next_json(ws, "hello")
        watcher.send_json({"type": "size", "size": [100, 50]})
        assert "cannot steer" in next_json(watcher, "error")["message"]
        default_viewer.send_json({"type": "size", "size": [100, 50]})
        driver.send_json({"type": "size", "size": [500, 100]})        # fitted to --max-size 200x100
        wait_until(lambda: client.get(f"/api/sessions/{body['id']}").json()["size"] == [200, 40], seconds(10),
                   "the session to take its driver's size")
        assert client.get("/api/sessions/default").json()["size"] == [64, 48]
        client.put(f"/api/sessions/{body['id']}/camera", json={"eye": [0, 0, 5], "target": [0, 0, 0]})
        renders = node.serve(lambda render: render["scene"] == "builtin:cluster")
        assert [r["size"] for r in renders if r["scene"] == "builtin:cluster"] == [[200, 40]]


def test_sessions_come_back_after_a_restart_with_their_ids_keys_sizes_cameras_and_balancers(tmp_path):
    settings = dataclasses.replace(SETTINGS, data_dir=tmp_path)
    camera = {"eye": [1.0, 2.0, 6.0], "target": [0.0, 0.5, 0.0], "up": [0.0, 1.0, 0.0], "fovy_deg": 40.0}
    with TestClient(create_app(settings)) as first:
        body = first.post("/api/sessions", json={"scene": "builtin:cluster", "size": [40, 20], "camera": camera}).json()
        first.put(f"/api/sessions/{body['id']}/balancer", json={"name": "static", "params": {}})
        first.put("/api/camera", json={"eye": [0.0, 0.0, 9.0], "target": [0.0, 0.0, 0.0]})
    assert not list(tmp_path.glob(".*.tmp")), "the file is written whole, then renamed"
    with TestClient(create_app(settings)) as second:
        again = second.get(f"/api/sessions/{body['id']}").json()
        assert again["size"] == [40, 20] and again["scene"] == "builtin:cluster"
        assert again["watch_url"] == body["watch_url"] and again["camera"]["eye"] == camera["eye"]
        assert second.get(f"/api/sessions/{body['id']}/balancer").json()["name"] == "static"
        assert second.get("/api/camera").json()["camera"]["eye"] == [0.0, 0.0, 9.0]
        watch = body["watch_url"].split("?")[1]
        with second.websocket_connect(f"/ws/view?{watch}") as viewer:
            assert next_json(viewer, "hello")["size"] == [40, 20]


def test_a_sessions_file_that_does_not_read_is_set_aside(tmp_path):
    (tmp_path / "sessions.json").write_text("{not json")
    with TestClient(create_app(dataclasses.replace(SETTINGS, data_dir=tmp_path))) as client:
        assert [s["id"] for s in client.get("/api/sessions").json()] == ["default"]
    assert (tmp_path / "sessions.json.bad").read_text() == "{not json"


def test_a_restored_session_gets_its_object_poses_back_once_a_node_reports_its_scene(tmp_path):
    settings = dataclasses.replace(SETTINGS, data_dir=tmp_path)
    with TestClient(create_app(settings)) as first:
        body = first.post("/api/sessions", json={"scene": "builtin:cluster"}).json()
        with first.websocket_connect("/ws/node") as ws:
            node = SceneNode(ws)
            node.serve(lambda render: render["scene"] == "builtin:spheres")
            wait_until(lambda: first.get(f"/api/sessions/{body['id']}/objects").status_code == 200, seconds(10),
                       "the session's scene")
            moved = first.put(f"/api/sessions/{body['id']}/objects/car", json={"translation": [3.0, 0.0, 0.0]})
            assert moved.status_code == 200
    with TestClient(create_app(settings)) as second:
        assert second.get(f"/api/sessions/{body['id']}/objects").status_code == 409, "no node reported it yet"
        with second.websocket_connect("/ws/node") as ws:
            node = SceneNode(ws)
            node.serve(lambda render: render["scene"] == "builtin:spheres")
            objects = wait_until(lambda: second.get(f"/api/sessions/{body['id']}/objects").json()
                                 if second.get(f"/api/sessions/{body['id']}/objects").status_code == 200 else None,
                                 seconds(10), "the restored session's scene")
            assert objects[0]["translation"] == [3.0, 0.0, 0.0]


def test_a_session_is_not_idle_while_a_request_waits_for_its_frame():
    """A REST user waiting for a big scene's still (no viewer) outlasted --session-idle-timeout-s:
    the session was closed under the waiting request. It stays open while one waits."""
    settings = dataclasses.replace(SETTINGS, session_idle_timeout_s=1.0)
    with TestClient(create_app(settings)) as client:
        session_id = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()["id"]
        waited = client.get(f"/api/sessions/{session_id}/frame.png", params={"still": "true", "timeout": 3.5})
        assert waited.status_code == 504, "no node: no frame, after the whole wait"
        assert client.get(f"/api/sessions/{session_id}").status_code == 200, "still open after the wait"
        wait_until(lambda: session_id not in {s["id"] for s in client.get("/api/sessions").json()}, seconds(10),
                   "the idle session closed once nothing waits")
