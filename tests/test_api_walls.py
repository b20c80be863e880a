"""Display walls over the API (issue 22), in process with a fake node whose tiles paint each
pixel with its own position: a wall session's frame is the whole wall; a cell viewer gets its
cell's part only, relative to the cell; cells steer nothing and are frame-locked; bad walls and
bad cells are refused with the reason; a wall survives a restart."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import Rect
from tessera.wire.codec import Codec, decode, encode
from tessera.wire.protocol import TileHeader, pack_tile, unpack_frame
from tests.conftest import seconds
from tests.integration_support import wait_until
from tests.test_api import BOUNDS, HELLO, closed_with, next_json
from tests.test_api_sessions import SETTINGS, frame_png

pytestmark = pytest.mark.timeout(seconds(120))
WALL = {"cols": 2, "rows": 2, "cell": [40, 30], "bezel": [4, 2]}
LAYOUT = WallLayout.from_json(WALL)
CAMERA = {"eye": [0, 0, 5], "target": [0, 0, 0]}


def position_image(width: int, height: int) -> np.ndarray:
    """(height, width, 3) uint8: red is x, green is y, blue 7."""
    ys, xs = np.mgrid[0:height, 0:width]
    return np.stack([xs, ys, np.full_like(xs, 7)], axis=-1).astype(np.uint8)


class PositionNode:
    """A fake node on ``/ws/node`` that loads every scene and answers each render with tiles cut from
    :func:`position_image` of the frame's size."""

    def __init__(self, ws) -> None:
        self.ws = ws
        ws.send_json(HELLO)
        next_json(ws, "welcome")

    def serve(self, until) -> list[dict[str, Any]]:
        renders = []
        while True:
            message = self.ws.receive_json()
            if message["type"] == "load_scene":
                self.ws.send_json({"type": "scene_ready", "scene": message["scene"], "triangles": 12,
                                   "bounds": BOUNDS, "objects": [{"name": "car", "bounds": BOUNDS}]})
            elif message["type"] == "render":
                image = position_image(*message["size"])
                for tile in message["tiles"]:
                    r = Rect(*tile["rect"])
                    header = TileHeader(message["frame"], tile["tile"], r, Codec.PNG, 1.0, 0.0, 0.0)
                    self.ws.send_bytes(pack_tile(header, encode(image[r.y:r.y1, r.x:r.x1], Codec.PNG)))
                    self.ws.send_json({"type": "tile_sent", "frame": message["frame"], "tile": tile["tile"],
                                       "send_ms": 0.1, "stats": {}})
                renders.append(message)
                if until(message):
                    return renders


@pytest.fixture
def client() -> Iterator[TestClient]:
    with TestClient(create_app(SETTINGS)) as client:
        yield client


def open_wall(client: TestClient, **extra: Any) -> dict[str, Any]:
    created = client.post("/api/sessions", json={"scene": "builtin:cluster", "wall": WALL, **extra})
    assert created.status_code == 201, created.text
    return created.json()


def next_frame(ws):
    while True:
        message = ws.receive()
        if message.get("bytes"):
            return unpack_frame(message["bytes"])


def test_a_wall_sessions_frame_is_the_whole_wall_and_its_size_is_fixed(client):
    body = open_wall(client)
    assert body["size"] == [84, 62]
    summary = client.get(f"/api/sessions/{body['id']}").json()
    assert summary["wall"] == WALL and summary["size"] == [84, 62]
    resized = client.put(f"/api/sessions/{body['id']}/size", json={"size": [60, 30]})
    assert resized.status_code == 409 and "fixed" in resized.text
    with client.websocket_connect("/ws/node") as ws:
        node = PositionNode(ws)
        first = client.put(f"/api/sessions/{body['id']}/camera", json=CAMERA).json()["frame"]
        renders = node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= first)
        wall_renders = [r for r in renders if r["scene"] == "builtin:cluster"]
        assert all(r["size"] == [84, 62] for r in wall_renders)
        cells = [LAYOUT.cell_rect(c, r) for c, r in LAYOUT.cells]
        for tile in wall_renders[-1]["tiles"]:   # every tile inside one cell, or in the bezel
            rect = Rect(*tile["rect"])
            touching = [c for c in cells if c.intersection_area(rect) > 0]
            assert not touching or touching[0].intersection_area(rect) == rect.area
        # one node's tile, the whole wall, cut into 9 pieces that name it (a node draws it once;
        # this fake node draws each piece, as a node of before did, and the frame is the same)
        assert {tuple(t["part_of"]) for t in wall_renders[-1]["tiles"]} == {(0, 0, 84, 62)}
        assert len(wall_renders[-1]["tiles"]) == 9
        frame = frame_png(client, f"/api/sessions/{body['id']}/frame.png", first)
        assert (frame == position_image(84, 62)).all()


def test_a_cell_gets_its_cells_tiles_relative_to_it_and_steers_nothing(client):
    body = open_wall(client)
    with client.websocket_connect("/ws/node") as node_ws, \
            client.websocket_connect(f"/ws/view?session={body['id']}&cell=1,1") as cell, \
            client.websocket_connect(f"/ws/view?session={body['id']}") as driver:
        node = PositionNode(node_ws)
        assert next_json(cell, "hello")["size"] == [40, 30]
        assert next_json(cell, "wall") == {"type": "wall", "wall": WALL, "cell": [1, 1]}
        assert next_json(driver, "hello")["size"] == [84, 62]
        assert next_json(driver, "wall")["cell"] is None
        cell.send_json({"type": "camera", "camera": CAMERA, "seq": 1})
        assert "cell of a wall" in next_json(cell, "error")["message"]
        driver.send_json({"type": "size", "size": [100, 50]})   # ignored: the wall's size is fixed
        driver.send_json({"type": "camera", "camera": CAMERA, "seq": 1})
        node.serve(lambda render: render["scene"] == "builtin:cluster")
        frame = next_frame(cell)
        assert frame.size == (40, 30)
        image = np.zeros((30, 40, 3), np.uint8)
        covered = 0
        for entry, payload in frame.tiles:
            r = entry.rect
            image[r.y:r.y1, r.x:r.x1] = decode(payload, entry.codec, r.w, r.h)
            covered += r.area
        assert covered == 40 * 30
        assert (image == position_image(84, 62)[32:62, 44:84]).all(), "the cell's own pixels"
        assert next_frame(driver).size == (84, 62)
        assert client.get(f"/api/sessions/{body['id']}").json()["size"] == [84, 62]


def next_text(ws, kind: str) -> dict[str, Any]:
    """The next text message of type ``kind``, skipping the others and the frames."""
    while True:
        message = ws.receive()
        if message.get("text") is not None and (data := json.loads(message["text"]))["type"] == kind:
            return data


def test_cells_are_frame_locked_and_their_skew_is_in_the_stats(client):
    body = open_wall(client)
    path = f"/ws/view?session={body['id']}"
    with client.websocket_connect("/ws/node") as node_ws, client.websocket_connect(f"{path}&cell=0,0") as left, \
            client.websocket_connect(f"{path}&cell=1,0") as right:
        node = PositionNode(node_ws)
        for ws in (left, right):
            next_text(ws, "wall")
        left.send_json({"type": "have", "frame": 1})
        assert "not published yet" in next_text(left, "error")["message"]   # a cell cannot claim frames to come
        for camera_x in (0, 1):   # frames to hold
            first = client.put(f"/api/sessions/{body['id']}/camera", json={**CAMERA, "eye": [camera_x, 0, 5]})
            node.serve(lambda render, first=first.json()["frame"]: render["scene"] == "builtin:cluster"
                       and render["frame"] >= first)
        newer = wait_until(lambda: client.get(f"/api/sessions/{body['id']}/stats").json()["frame"], seconds(10),
                           "a published frame")
        older = newer - 1
        left.send_json({"type": "ping", "t0": 12.5})
        pong = next_text(left, "pong")
        assert pong["t0"] == 12.5 and pong["clock_ms"] > 0
        left.send_json({"type": "have", "frame": older})
        right.send_json({"type": "have", "frame": newer})
        present = next_text(right, "present")
        assert present["frame"] == older and present["at_ms"] > pong["clock_ms"]   # both hold it; a moment ahead
        assert next_text(left, "present")["frame"] == older
        left.send_json({"type": "presented", "frame": older, "at_ms": 1000.0})
        right.send_json({"type": "presented", "frame": older, "at_ms": 1004.0})
        left.send_json({"type": "have", "frame": newer})
        assert next_text(left, "present")["frame"] == newer
        left.send_json({"type": "have", "frame": -1})
        assert "frame" in next_text(left, "error")["message"]
        lock = client.get(f"/api/sessions/{body['id']}/stats").json()["frame_lock"]
        assert lock["skew_samples"] == 1 and lock["skew_p50_ms"] == 4.0 and lock["cells"] == 2
        assert next_text(right, "present")["frame"] == newer
        with client.websocket_connect(f"{path}&cell=1,1") as laggard:
            next_text(laggard, "wall")
            moved = client.put(f"/api/sessions/{body['id']}/camera", json={**CAMERA, "eye": [2, 0, 5]}).json()["frame"]
            node.serve(lambda render: render["scene"] == "builtin:cluster" and render["frame"] >= moved)
            newest = wait_until(lambda: (f := client.get(f"/api/sessions/{body['id']}/stats").json()["frame"]) > newer
                                and f, seconds(10), "a newer frame")
            for ws in (left, right):
                ws.send_json({"type": "have", "frame": newest})   # the new cell holds nothing yet: no present
            left.send_json({"type": "ping", "t0": 1.0})
            assert next_text(left, "pong")["t0"] == 1.0
        assert next_text(right, "present")["frame"] == newest, "a cell that leaves holds no one back"


@pytest.mark.parametrize(("wall", "why"), [
    ({"cols": 0, "rows": 2, "cell": [40, 30]}, "at least one cell"),
    ({"cols": 2, "rows": 0, "cell": [40, 30]}, "at least one cell"),
    ({"cols": 2, "rows": 2, "cell": [0, 30]}, "at least 1x1"),
    ({"cols": 2, "rows": 2, "cell": [40, 300]}, "--max-size"),
    ({"cols": 2, "rows": 2, "cell": [300, 30]}, "--max-size"),
    ({"cols": 8, "rows": 8, "cell": [200, 100]}, "pixel budget"),
    ({"cols": 2, "rows": 2, "cell": [40, 30], "bezel": [-1, 0]}, "at least 0 px"),
    ({"cols": 2, "rows": 2, "cell": [40]}, "cell"),
    ({"cols": 2, "rows": 2, "cell": [40, 30], "size": 3}, "size"),
])
def test_bad_walls_are_refused_with_the_reason(client, wall, why):
    refused = client.post("/api/sessions", json={"scene": "builtin:cluster", "wall": wall})
    assert refused.status_code == 422 and why in refused.text, refused.text


def test_a_wall_and_a_size_together_are_refused(client):
    refused = client.post("/api/sessions", json={"scene": "builtin:cluster", "wall": WALL, "size": [10, 10]})
    assert refused.status_code == 422 and "wall or size" in refused.text


def test_bad_cells_close_the_socket_with_the_reason(client):
    body = open_wall(client)
    plain = client.post("/api/sessions", json={"scene": "builtin:cluster"}).json()
    for query, why in ((f"session={body['id']}&cell=2,0", "outside the wall"),
                       (f"session={body['id']}&cell=0,2", "outside the wall"),
                       (f"session={body['id']}&cell=-1,0", "COL,ROW"),
                       (f"session={body['id']}&cell=x", "COL,ROW"),
                       (f"session={plain['id']}&cell=0,0", "not a wall")):
        with client.websocket_connect(f"/ws/view?{query}") as ws:
            code, reason = closed_with(ws)
            assert code == 4422 and why in reason


def test_a_wall_comes_back_after_a_restart(tmp_path):
    settings = dataclasses.replace(SETTINGS, data_dir=tmp_path)
    with TestClient(create_app(settings)) as first:
        body = open_wall(first)
    with TestClient(create_app(settings)) as second:
        summary = second.get(f"/api/sessions/{body['id']}").json()
        assert summary["wall"] == WALL and summary["size"] == [84, 62]
        with second.websocket_connect(f"/ws/view?session={body['id']}&cell=1,1") as cell:
            assert next_json(cell, "hello")["size"] == [40, 30]


def test_a_wall_needs_the_sort_first_mode():
    with TestClient(create_app(dataclasses.replace(SETTINGS, mode="hybrid"))) as client:
        refused = client.post("/api/sessions", json={"scene": "builtin:cluster", "wall": WALL})
        assert refused.status_code == 422 and "--mode sort-first" in refused.text
