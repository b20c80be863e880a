"""``/api/objects`` and ``/api/animation`` in process (issue 11): a fake node reports a scene with
objects and an animation and answers every ``render`` in the state the message brings it to; the
API's frames show what was asked (404, 422 and 409 change nothing), a playing animation keeps
frames coming, ``frame.png`` says which state it shows."""

from __future__ import annotations

import io
import json
import math
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from server.app import create_app
from server.settings import Settings
from tessera.geometry import Rect
from tessera.scene.state import SceneState, StateReplica, state_from_json
from tessera.wire.codec import Codec, encode
from tessera.wire.protocol import TileHeader, pack_tile, state_tag
from tests.conftest import seconds
from tests.integration_support import wait_until
from tests.test_api import HELLO, WAIT_S, next_json

pytestmark = pytest.mark.timeout(seconds(120))

BOX = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
OBJECTS = [{"name": "car", "translation": [0.0, 0.0, 0.0], "bounds": BOX, "triangles": 100},
           {"name": "wheel", "parent": "car", "translation": [1.0, 0.0, 0.0], "triangles": 20,
            "bounds": [[0.5, -0.5, -0.5], [1.5, 0.5, 0.5]]},
           {"name": "tree", "translation": [5.0, 0.0, 0.0], "bounds": [[4.0, -1.0, -1.0], [6.0, 3.0, 1.0]],
            "triangles": 50}]
#: ``car`` drives from x = 0 to x = 10 over [0, 2] s.
DRIVE = {"name": "drive", "channels": [{"target": "car", "path": "translation", "interpolation": "LINEAR",
                                        "times": [0.0, 2.0], "values": [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]}]}


class SceneNode:
    """A node on ``/ws/node`` that reports :data:`OBJECTS` (and ``animations``) and answers each
    ``render`` with flat PNG tiles tagged with the state the message brings it to."""

    def __init__(self, ws, animations: list[dict[str, Any]]) -> None:
        self.ws = ws
        self.replica = StateReplica()
        self.states: dict[int, SceneState] = {}
        ws.send_json(HELLO)
        next_json(ws, "welcome")
        next_json(ws, "load_scene")
        ws.send_json({"type": "scene_ready", "triangles": 170, "bounds": [[-1, -1, -1], [6, 3, 1]],
                      "objects": OBJECTS, "animations": animations})

    def answer_until(self, frame: int) -> SceneState:
        """Answer every render message until one for ``frame`` or later; the state of that frame."""
        while True:
            render = next_json(self.ws, "render")
            state = self.replica.receive(state_from_json(render["state"]))
            self.states[render["frame"]] = state
            codec = Codec.parse(render["codec"])
            for tile in render["tiles"]:
                rect = Rect(*tile["rect"])
                pixels = np.full((rect.h, rect.w, 3), 30, dtype=np.uint8)
                header = TileHeader(render["frame"], tile["tile"], rect, codec, 1.0, 1.0, 1.0, state_tag(state.version))
                self.ws.send_bytes(pack_tile(header, encode(pixels, codec)))
                self.ws.send_json({"type": "tile_sent", "frame": render["frame"], "tile": tile["tile"], "send_ms": 0.1})
            if render["frame"] >= frame:
                return state


@pytest.fixture
def client():
    settings = Settings(scene="builtin:spheres", size=(64, 48), codec=Codec.PNG, still_codec=None, settle_frames=0)
    with TestClient(create_app(settings)) as client:
        yield client


def objects(client: TestClient) -> dict[str, dict[str, Any]]:
    return {o["name"]: o for o in client.get("/api/objects").raise_for_status().json()}


def test_before_a_node_reports_the_scene_there_is_nothing_to_pose(client):
    assert client.get("/api/objects").status_code == 409
    assert client.put("/api/objects/car", json={"visible": False}).status_code == 409
    assert client.get("/api/animation").status_code == 409
    paths = client.get("/openapi.json").json()["paths"]
    assert "put" in paths["/api/objects/{name}"] and "put" in paths["/api/animation"] and "/api/objects" in paths


def test_objects_are_listed_and_posed_from_the_frame_the_put_returns(client):
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws, [DRIVE])
        node.answer_until(1)
        listed = objects(client)
        assert list(listed) == ["car", "wheel", "tree"]
        assert listed["wheel"]["parent"] == "car" and listed["car"]["triangles"] == 100
        assert listed["car"]["rotation"] == [0.0, 0.0, 0.0, 1.0] and listed["car"]["visible"] is True
        assert listed["wheel"]["bounds"] == [[0.5, -0.5, -0.5], [1.5, 0.5, 0.5]]

        frame = client.put("/api/objects/car", json={"translation": [0.0, 2.0, 0.0]}).json()["frame"]
        last = client.put("/api/objects/tree", json={"visible": False, "scale": [2, 2, 2]}).json()["frame"]
        assert last >= frame
        state = node.answer_until(last)
        assert state.objects["car"].translation == (0.0, 2.0, 0.0) and not state.objects["tree"].visible
        assert node.states[frame].objects["car"].translation == (0.0, 2.0, 0.0)
        listed = objects(client)
        assert listed["car"]["translation"] == [0.0, 2.0, 0.0] and listed["tree"]["scale"] == [2.0, 2.0, 2.0]
        assert listed["wheel"]["bounds"] == [[0.5, 1.5, -0.5], [1.5, 2.5, 0.5]], "a child moves with its parent"

        response = client.get("/api/frame.png", params={"after": last})
        assert response.status_code == 200
        version = int(response.headers["x-state-version"])
        assert version == node.states[int(response.headers["x-frame-id"])].version
        assert set(response.headers["x-tile-states"].split(",")) == {str(version)}
        assert float(response.headers["x-scene-time"]) == 0.0
        assert Image.open(io.BytesIO(response.content)).size == (64, 48)


@pytest.mark.parametrize("name, body, status, detail", [
    ("bus", {"visible": False}, 404, "unknown object 'bus'"),
    ("car", {"translation": [1.0, 2.0]}, 422, "car.translation must be a list of 3 numbers"),
    ("car", {"rotation": [0, 0, 0, 0]}, 422, "car.rotation must be a quaternion of non-zero length"),
    ("car", {"scale": [0, 1, 1]}, 422, "car.scale must be non-zero"),
    ("car", {"translation": [math.nan, 0, 0]}, 422, "car.translation is not finite"),
    ("car", {"translation": ["1", 0, 0]}, 422, "translation"),
    ("car", {"visible": "yes"}, 422, "visible"),
    ("car", {"colour": [1, 0, 0]}, 422, "colour"),
])
def test_a_bad_pose_changes_nothing(client, name, body, status, detail):
    with client.websocket_connect("/ws/node") as ws:
        SceneNode(ws, [DRIVE]).answer_until(1)
        before = objects(client)
        scheduler = client.app.state.service.scheduler
        frames = scheduler.next_frame_id, client.get("/api/stats").json()["scene_state"]
        response = client.put(f"/api/objects/{name}", content=json.dumps(body, allow_nan=True),
                              headers={"Content-Type": "application/json"})
        assert response.status_code == status, response.text
        assert detail in json.dumps(response.json()["detail"])
        assert objects(client) == before
        assert (scheduler.next_frame_id, client.get("/api/stats").json()["scene_state"]) == frames, \
            "no frame started, the state is the same"


def test_animation_time_speed_and_play(client):
    with client.websocket_connect("/ws/node") as ws:
        node = SceneNode(ws, [DRIVE])
        node.answer_until(1)
        animation = client.get("/api/animation").json()
        assert animation == {"playing": False, "time": 0.0, "speed": 1.0, "start": 0.0, "end": 2.0,
                             "animations": [{"name": "drive", "start": 0.0, "end": 2.0, "targets": ["car"]}]}
        frame = client.put("/api/animation", json={"time": 0.5}).json()["frame"]
        state = node.answer_until(frame)
        assert state.time == 0.5 and state.objects["car"].translation == (2.5, 0.0, 0.0)
        assert objects(client)["car"]["translation"] == [2.5, 0.0, 0.0]
        for body, detail in (({"time": "soon"}, "time"), ({"speed": 1e9}, "speed must be within"),
                             ({"playing": 1}, "playing"), ({"loop": True}, "loop")):
            response = client.put("/api/animation", json=body)
            assert response.status_code == 422 and detail in json.dumps(response.json()["detail"]), response.text
        assert client.get("/api/animation").json()["time"] == 0.5

        playing = client.put("/api/animation", json={"playing": True, "speed": 0.25}).json()["frame"]
        first = node.answer_until(playing)
        later = node.answer_until(playing + 3)
        assert later.version > first.version and later.time > first.time, "frames keep coming with new states"
        scene_state = client.get("/api/stats").json()["scene_state"]
        assert scene_state["playing"] is True and scene_state["version"] >= later.version
        paused = client.put("/api/animation", json={"playing": False}).json()["frame"]
        held = node.answer_until(paused)
        assert client.get("/api/animation").json()["time"] == held.time


def test_a_scene_without_animations_has_nothing_to_play(client):
    with client.websocket_connect("/ws/node") as ws:
        SceneNode(ws, []).answer_until(1)
        assert client.get("/api/animation").json()["animations"] == []
        response = client.put("/api/animation", json={"playing": True})
        assert response.status_code == 409 and "no animations" in response.json()["detail"]
        assert client.get("/api/stats").json()["scene_state"] == {"version": 0, "time": 0.0, "playing": False,
                                                                  "speed": 1.0, "animated": False}


def test_a_node_reporting_a_broken_scene_is_closed_with_the_reason(client):
    with client.websocket_connect("/ws/node") as ws:
        ws.send_json(HELLO)
        next_json(ws, "welcome")
        next_json(ws, "load_scene")
        ws.send_json({"type": "scene_ready", "triangles": 1, "bounds": BOX, "objects": OBJECTS,
                      "animations": [{**DRIVE, "channels": [{**DRIVE["channels"][0], "target": "bus"}]}]})
        while (message := ws.receive())["type"] != "websocket.close":
            pass
        assert message["code"] == 1008 and "unknown object 'bus'" in message["reason"]
    wait_until(lambda: client.get("/api/stats").json()["nodes"] == [], WAIT_S, "the node to leave", interval=0.01)
