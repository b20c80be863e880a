"""The coordinator in the depth modes, in process (FastAPI's TestClient, fake nodes, no GL): a node
that cannot render depth tiles is refused with the reason, a sort-last node is told its share and
its frames start once it holds it, depth tiles are checked against what their frame expects (a
plain tile, a core short of the tile's, another partition's share: closed with the reason), and a
frame of depth tiles is merged and published as colour."""

from __future__ import annotations

import io
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from server.app import create_app
from server.settings import Settings
from tessera.compositing.layers import DepthLayer, background_pixel
from tessera.geometry import DEFAULT_BACKGROUND, Rect
from tessera.wire.codec import Codec, encode
from tessera.wire.depth_tiles import encode_depth_tile
from tessera.wire.protocol import PROTOCOL_VERSION, TileHeader, pack_tile
from tests.integration_support import wait_until
from tests.test_api import BOUNDS, WAIT_S, closed_with, next_json

SIZE = (64, 48)


def hello(depth: bool = True) -> dict[str, Any]:
    return {"type": "hello", "name": "fake", "version": PROTOCOL_VERSION,
            "capabilities": {"calibrate": False, "depth": depth}}


@pytest.fixture
def hybrid() -> Iterator[TestClient]:
    settings = Settings(scene="builtin:spheres", size=SIZE, codec=Codec.PNG, mode="hybrid", depth_strip=8)
    with TestClient(create_app(settings)) as client:
        yield client


@pytest.fixture
def sort_last() -> Iterator[TestClient]:
    with TestClient(create_app(Settings(scene="builtin:spheres", size=SIZE, codec=Codec.PNG,
                                        mode="sort-last"))) as client:
        yield client


def join(ws, share: bool = False) -> dict[str, Any]:
    """A fake node joins and reports its scene (or share) loaded; returns its load_scene."""
    ws.send_json(hello())
    next_json(ws, "welcome")
    load = next_json(ws, "load_scene")
    ready = {"type": "scene_ready", "triangles": 12, "bounds": BOUNDS}
    if share:
        ready["share"] = load["share"]["version"]
    ws.send_json(ready)
    return load


def send_depth_tile(ws, render: dict[str, Any], tile: dict[str, Any], payload: bytes) -> None:
    header = TileHeader(render["frame"], tile["tile"], Rect(*tile["rect"]), Codec.parse(render["codec"]), 1.0, 0.5,
                        0.5, depth=True)
    ws.send_bytes(pack_tile(header, payload))
    ws.send_json({"type": "tile_sent", "frame": render["frame"], "tile": tile["tile"], "send_ms": 0.1,
                  "stats": {"triangles": 6}})


def test_a_node_without_depth_tiles_is_refused_with_the_reason(hybrid):
    with hybrid.websocket_connect("/ws/node") as ws:
        ws.send_json(hello(depth=False))
        code, reason = closed_with(ws)
    assert code == 1008 and "--mode hybrid" in reason and "depth" in reason


def test_hybrid_render_messages_list_the_partition_and_plain_tiles_are_refused(hybrid):
    with hybrid.websocket_connect("/ws/node") as ws:
        join(ws)
        render = next_json(ws, "render")
        assert render["depth"] == {"mode": "hybrid", "tiles": [[0, 0, 64, 48]], "strip": 8, "share": 0}
        tile = render["tiles"][0]
        header = TileHeader(render["frame"], tile["tile"], Rect(*tile["rect"]), Codec.PNG, 1.0, 0.5, 0.5)
        ws.send_bytes(pack_tile(header, encode(np.zeros((48, 64, 3), np.uint8), Codec.PNG)))
        code, reason = closed_with(ws)
    assert code == 1008 and "is not a depth tile" in reason, reason


def test_a_depth_tile_whose_core_falls_short_of_its_tile_s_is_refused(hybrid):
    """One tile covers the frame: no strip reaches it, so all of it is its core."""
    with hybrid.websocket_connect("/ws/node") as ws:
        join(ws)
        render = next_json(ws, "render")
        layer = DepthLayer(Rect(0, 0, 64, 48), np.zeros((48, 64, 3), np.uint8), np.full((48, 64), 0.5, np.float32), 0)
        payload, _ = encode_depth_tile(layer, Rect(0, 0, 32, 48), Codec.PNG, 90)
        send_depth_tile(ws, render, render["tiles"][0], payload)
        code, reason = closed_with(ws)
    assert code == 1008 and "depth tile core [0, 0, 32, 48]" in reason, reason


def test_sort_last_nodes_get_shares_and_their_depth_tiles_are_merged(sort_last):
    with sort_last.websocket_connect("/ws/node") as ws:
        load = join(ws, share=True)
        assert load["share"] == {"version": 1, "index": 0, "weights": [1.0]}
        render = next_json(ws, "render")
        assert render["depth"]["mode"] == "sort-last" and render["depth"]["share"] == 1
        (tile,) = render["tiles"]
        assert tile["rect"] == [0, 0, *SIZE]
        stats = sort_last.get("/api/stats").json()
        assert stats["mode"] == "sort-last" and stats["partition"]["holders"] == [stats["nodes"][0]["id"]]
        rect = Rect(10, 12, 20, 16)
        color = np.full((rect.h, rect.w, 3), 200, np.uint8)
        layer = DepthLayer(rect, color, np.full((rect.h, rect.w), 0.5, np.float32), 0)
        wrong, _ = encode_depth_tile(layer, None, Codec.PNG, 90, version=7)
        payload, _ = encode_depth_tile(layer, None, Codec.PNG, 90, version=1)
        send_depth_tile(ws, render, tile, payload)
        wait_until(lambda: sort_last.get("/api/stats").json()["frame"] >= render["frame"], WAIT_S, "the merged frame",
                   interval=0.01)
        response = sort_last.get("/api/frame.png", params={"after": render["frame"]})
        image = np.asarray(Image.open(io.BytesIO(response.content)).convert("RGB"))
        assert (image[12:28, 10:30] == 200).all()
        assert (image[0, 0] == background_pixel(DEFAULT_BACKGROUND)).all(), "the background, painted once"
        wait_until(lambda: sort_last.get("/api/stats").json()["nodes"][0]["readback"] == [rect.as_list()], WAIT_S,
                   "the stats to show where the node drew (the rect its share projects to)", interval=0.01)
        stats = sort_last.get("/api/stats").json()
        assert stats["nodes"][0]["share"] == 1 and stats["coordinator_cpu"]["merge_ms"] > 0.0
        assert stats["nodes"][0]["tiles"] == [[0, 0, *SIZE]]
        sort_last.put("/api/camera", json={"eye": [0, 1, 5], "target": [0, 0, 0]})
        render = next_json(ws, "render")
        send_depth_tile(ws, render, render["tiles"][0], wrong)
        code, reason = closed_with(ws)
    assert code == 1008 and "partition 7" in reason, reason
