"""The node process: its settings (argv over ``TESSERA_*`` environment), and its network loop
against a tiny fake coordinator (a real websockets server on port 0): hello, scene loading, tiles in
order with their ``tile_sent``, errors, slowdown, reconnection."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import os
import tempfile
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.server import ServerConnection, serve

from node.client import NodeClient
from node.culling.switch import SOFTWARE_RENDERERS, CullMode
from node.gl.renderer import TileRenderer
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.settings import NodeSettings, parse_settings
from tessera.geometry import DEFAULT_BACKGROUND, Camera, Rect
from tessera.scene.state import ObjectPatch
from tessera.wire.codec import Codec, decode
from tessera.wire.protocol import PROTOCOL_VERSION, unpack_tile
from tests.conftest import seconds

SIZE = (96, 64)
BACKGROUND = (0.2, 0.4, 0.6)
CAMERA = {"eye": [0.5, 1.6, 3.2], "target": [-0.2, 0.4, 0.0], "fovy_deg": 45}
SLOWDOWN = 3.0


class FakeCoordinator:
    """Hands each accepted node connection to the test, which then plays the coordinator."""

    def __init__(self) -> None:
        self.connections: asyncio.Queue[ServerConnection] = asyncio.Queue()

    async def handler(self, ws: ServerConnection) -> None:
        self.connections.put_nowait(ws)
        await ws.wait_closed()

    async def accept(self) -> ServerConnection:
        return await asyncio.wait_for(self.connections.get(), seconds(20))


async def receive(ws: ServerConnection) -> str | bytes:
    return await asyncio.wait_for(ws.recv(), seconds(30))


async def receive_json(ws: ServerConnection) -> dict:
    message = await receive(ws)
    assert isinstance(message, str), "expected a JSON control message"
    return json.loads(message)


async def send(ws: ServerConnection, **message) -> None:
    await ws.send(json.dumps(message))


async def receive_tile(ws: ServerConnection, frame: int, tile: int, scene: dict):
    """A binary tile and the ``tile_sent`` right after it, whose culling counters fit ``scene``
    (the ``scene_ready`` message); returns (header, pixels, stats)."""
    binary = await receive(ws)
    assert isinstance(binary, bytes), f"expected tile {tile}, got {binary!r}"
    header, payload = unpack_tile(binary)
    assert (header.frame_id, header.tile_id, header.codec) == (frame, tile, Codec.PNG)
    sent = await receive_json(ws)
    assert sent["type"] == "tile_sent" and (sent["frame"], sent["tile"]) == (frame, tile)
    stats = sent["stats"]
    assert sent["send_ms"] >= 0.0 and set(stats) == {"triangles", "chunks_drawn", "chunks_culled", "cull_ms",
                                                     "cull_path"}
    assert stats["chunks_drawn"] + stats["chunks_culled"] == scene["chunks"]
    assert 0 <= stats["triangles"] <= scene["triangles"] and stats["cull_ms"] >= 0.0
    assert stats["cull_path"] in (("cpu",) if scene["software"] else ("cpu", "gpu")), "auto: the CPU on llvmpipe"
    return header, decode(bytes(payload), header.codec, header.rect.w, header.rect.h), stats


async def play_coordinator(coordinator: FakeCoordinator,
                           scene_data: SceneData) -> tuple[np.ndarray, list[float], np.ndarray]:
    """The whole conversation with a node that loads ``scene_data``'s scene; returns the stitched
    frame-1 image, its tiles' render_ms and the stitched frame in :data:`MOVED`."""
    triangles, chunks = scene_data.triangle_count, scene_data.chunks.chunk_count
    ws = await coordinator.accept()
    hello = await receive_json(ws)
    assert hello["type"] == "hello" and hello["name"] == "tester" and hello["token"] == "s3cret"
    assert hello["version"] == PROTOCOL_VERSION and hello["renderer"]
    assert hello["capabilities"] == {"slowdown": SLOWDOWN, "calibrate": True, "depth": True}
    await send(ws, type="welcome", node_id=7)
    await send(ws, type="load_scene", scene="builtin:spheres", background=list(BACKGROUND))
    progress = []
    while (message := await receive_json(ws))["type"] == "scene_progress":
        progress.append(message["fraction"])
    assert message["type"] == "scene_ready" and progress == sorted(progress) and progress
    assert set(message) == {"type", "scene", "triangles", "bounds", "groups", "objects", "animations", "scene_mb",
                            "held_mb", "rss_mb"}, \
        "what the coordinator reads, no more"
    assert message["scene"] == "builtin:spheres", "the spec loaded, echoed"
    assert [o["name"] for o in message["objects"]] == list(scene_data.objects.names)
    assert message["animations"] == []
    assert message["triangles"] == triangles and np.allclose(message["bounds"], scene_data.bounds)
    assert chunks > 5, "the spheres' meshes are split into octree chunks"
    assert len(message["groups"]["boxes"]) == len(message["groups"]["counts"]) == chunks
    assert sum(message["groups"]["counts"]) == triangles
    scene = {**message, "chunks": chunks, "software": any(name in hello["renderer"] for name in SOFTWARE_RENDERERS)}

    tiles = [{"tile": 0, "rect": [0, 0, 50, 64]}, {"tile": 1, "rect": [50, 0, 46, 64]}]
    await send(ws, type="render", frame=1, camera=CAMERA, size=list(SIZE), codec="png", jpeg_quality=80, tiles=tiles)
    stitched = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    render_ms = []
    drawn = []
    for tile in (0, 1):
        header, pixels, stats = await receive_tile(ws, 1, tile, scene)
        stitched[header.rect.y:header.rect.y1, header.rect.x:header.rect.x1] = pixels
        render_ms.append(header.render_ms)
        drawn.append(stats["triangles"])
    assert sum(drawn) > 0 and max(drawn) < triangles, "each half of the frame draws only part of the scene"

    await send(ws, type="render", frame=2, camera={"eye": [1, 1, 1], "target": [1, 1, 1]}, size=list(SIZE),
               codec="png", tiles=tiles)
    for tile in (0, 1):
        error = await receive_json(ws)
        assert error["type"] == "render_error" and (error["frame"], error["tile"]) == (2, tile)
        assert "camera" in error["message"]

    await send(ws, type="render", frame=3, camera=CAMERA, size=list(SIZE), codec="png",
               tiles=[{"tile": 0, "rect": [90, 0, 10, 10]}, {"tile": 1, "rect": [0, 0, 8, 8]}])
    error = await receive_json(ws)
    assert error["type"] == "render_error" and (error["frame"], error["tile"]) == (3, 0)
    await receive_tile(ws, 3, 1, scene)

    await send(ws, type="calibrate", camera=CAMERA, size=list(SIZE), rect=[24, 16, 48, 32], repeats=2)
    calibration = await receive_json(ws)
    assert calibration["type"] == "calibration" and calibration["ms"] > 0.0
    render_ms.append(calibration["ms"])

    await superseded_tiles_are_dropped(ws)
    moved = await frames_show_their_scene_state(ws, scene_data, tiles, scene)

    await ws.close(4401, "wrong token")
    ws = await coordinator.accept()
    assert (await receive_json(ws))["type"] == "hello"
    await send(ws, type="welcome", node_id=8)
    await send(ws, type="load_scene", scene="builtin:spheres", background=list(BACKGROUND))
    assert (await receive_json(ws))["type"] == "scene_ready", "the loaded scene must be reused, not reloaded"
    await send(ws, type="render", frame=1, camera=CAMERA, size=list(SIZE), codec="png", tiles=tiles[:1],
               state={"base": 4, "version": 5, "time": 0.0, "objects": {}})
    error = await receive_json(ws)
    assert error["type"] == "render_error" and "before any full state" in error["message"], \
        "a new connection starts without a state"
    return stitched, render_ms, moved


#: sphere0 moved right and grown, sphere2 hidden (version 3 of the state).
MOVED = {"sphere0": ObjectPatch(translation=(0.9, 0.5, 0.2), scale=(1.3, 1.3, 1.3)),
         "sphere2": ObjectPatch(visible=False)}


async def frames_show_their_scene_state(ws: ServerConnection, scene_data: SceneData, tiles: list[dict],
                                        scene: dict) -> np.ndarray:
    """Frame 5 carries a full state (version 3), frame 6 a delta to version 4, frame 7 a delta on a
    version the node never had: tiles say the version they show, the last frame fails. Returns
    frame 5 stitched."""
    full = dataclasses.replace(scene_data.state_at(0.0, MOVED), version=3)
    await send(ws, type="render", frame=5, camera=CAMERA, size=list(SIZE), codec="png", tiles=tiles,
               state=full.to_json())
    stitched = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    for tile in (0, 1):
        header, pixels, _ = await receive_tile(ws, 5, tile, scene)
        assert header.state == 3
        stitched[header.rect.y:header.rect.y1, header.rect.x:header.rect.x1] = pixels
    delta = full.patched({"sphere0": ObjectPatch(translation=(0.0, 0.0, 0.0))}).delta_from(full)
    await send(ws, type="render", frame=6, camera=CAMERA, size=list(SIZE), codec="png", tiles=tiles[:1],
               state=delta.to_json())
    header, _, _ = await receive_tile(ws, 6, 0, scene)
    assert header.state == 4
    await send(ws, type="render", frame=7, camera=CAMERA, size=list(SIZE), codec="png", tiles=tiles,
               state={"base": 9, "version": 10, "time": 0.0, "objects": {}})
    for tile in (0, 1):
        error = await receive_json(ws)
        assert error["type"] == "render_error" and (error["frame"], error["tile"]) == (7, tile)
        assert "scene state" in error["message"] and "does not apply" in error["message"]
    return stitched


CANCEL_SIZE = (3840, 2160)
CANCEL_TILES = [{"tile": i, "rect": [i * 480, 0, 480, 2160]} for i in range(8)]


async def superseded_tiles_are_dropped(ws: ServerConnection) -> None:
    """A frame of 8 large tiles is cancelled once its first tile is back: the node skips the tiles
    it had not begun and says which."""
    await send(ws, type="render", frame=4, camera=CAMERA, size=list(CANCEL_SIZE), codec="jpeg", tiles=CANCEL_TILES)
    rendered = [unpack_tile(await receive(ws))[0].tile_id]
    await send(ws, type="cancel", frames=[4])
    while True:
        message = await receive(ws)
        if isinstance(message, bytes):
            rendered.append(unpack_tile(message)[0].tile_id)
            continue
        message = json.loads(message)
        if message["type"] == "tiles_dropped":
            break
        assert message["type"] == "tile_sent" and message["frame"] == 4
    assert message["frame"] == 4 and message["tiles"], "the queued tiles of the cancelled frame are dropped"
    assert sorted(rendered + message["tiles"]) == list(range(8)), "each tile rendered or dropped, once"
    assert message["tiles"] == list(range(len(rendered), 8)), "the tiles not begun yet, in order"


async def run_node_against_fake() -> tuple[np.ndarray, list[float], list[float], np.ndarray]:
    coordinator = FakeCoordinator()
    slept: list[float] = []

    async def record_sleep(duration: float) -> None:
        slept.append(duration)

    async with serve(coordinator.handler, "127.0.0.1", 0) as server:
        port = server.sockets[0].getsockname()[1]
        settings = NodeSettings(coordinator=f"ws://127.0.0.1:{port}/ws/node", name="tester", token="s3cret",
                                slowdown=SLOWDOWN)
        stop = asyncio.Event()
        node = asyncio.create_task(NodeClient(settings, sleep=record_sleep).run(stop))
        try:
            stitched, render_ms, moved = await play_coordinator(coordinator, load_scene("builtin:spheres"))
        finally:
            stop.set()
            await asyncio.wait_for(node, seconds(30))
    return stitched, render_ms, slept, moved


def test_settings_come_from_environment_and_argv_wins():
    environ = {"TESSERA_COORDINATOR": "ws://render-hub:9000/ws/node", "TESSERA_TOKEN": "t0k", "TESSERA_NAME": "gpu-7",
               "TESSERA_SLOWDOWN": "2.5", "TESSERA_SIZE": "640x360", "TESSERA_BACKGROUND": "#1c1f26"}
    settings = parse_settings([], environ)
    assert settings == NodeSettings(coordinator="ws://render-hub:9000/ws/node", name="gpu-7", token="t0k",
                                    slowdown=2.5, size=(640, 360), background=(28 / 255, 31 / 255, 38 / 255))
    overridden = parse_settings(["--slowdown", "1", "--background", "0.2,0.4,0.6", "--render-once", "x.png"], environ)
    assert overridden.slowdown == 1.0 and overridden.background == (0.2, 0.4, 0.6)
    assert str(overridden.render_once) == "x.png" and overridden.token == "t0k"


def test_settings_defaults():
    settings = parse_settings([], {})
    assert settings.token is None and settings.slowdown == 1.0 and settings.render_once is None
    assert settings.background == DEFAULT_BACKGROUND and settings.scene == "builtin:cluster"
    assert settings.name.endswith(f"-{os.getpid()}")
    assert settings.culling is CullMode.AUTO and settings.face_limit == DEFAULT_FACE_LIMIT
    assert settings.scene_memory_mb == 2048
    assert settings.scene_cache_dir == Path(tempfile.gettempdir()) / "tessera-scenes"


def test_culling_settings_from_environment_and_argv():
    environ = {"TESSERA_CULLING": "gpu", "TESSERA_FACE_LIMIT": "512"}
    assert (parse_settings([], environ).culling, parse_settings([], environ).face_limit) == (CullMode.GPU, 512)
    overridden = parse_settings(["--culling", "off", "--face-limit", "64", "--render-once", "x.png"], environ)
    assert (overridden.culling, overridden.face_limit) == (CullMode.OFF, 64)


def test_scene_settings_from_environment_and_argv():
    environ = {"TESSERA_SCENE_MEMORY_MB": "512", "TESSERA_SCENE_CACHE_DIR": "/var/cache/tessera"}
    settings = parse_settings([], environ)
    assert (settings.scene_memory_mb, settings.scene_cache_dir) == (512, Path("/var/cache/tessera"))
    overridden = parse_settings(["--scene-memory-mb", "64", "--scene-cache-dir", "cache"], environ)
    assert (overridden.scene_memory_mb, overridden.scene_cache_dir) == (64, Path("cache"))


@pytest.mark.parametrize("argv", [["--slowdown", "0.5"], ["--slowdown", "nan"], ["--size", "0x10"],
                                  ["--size", "big"], ["--background", "#12345"], ["--background", "0,0,2"],
                                  ["--coordinator", "http://host:8000/ws/node"], ["--culling", "sometimes"],
                                  ["--face-limit", "0"], ["--face-limit", "1.5"], ["--scene-memory-mb", "0"],
                                  ["--scene-memory-mb", "lots"]])
def test_settings_refuse_bad_values(argv, capsys):
    with pytest.raises(SystemExit) as exited:
        parse_settings(argv, {})
    assert exited.value.code != 0
    assert argv[0] in capsys.readouterr().err


@pytest.mark.gl
def test_node_serves_a_fake_coordinator(ctx):
    stitched, render_ms, slept, moved = asyncio.run(run_node_against_fake())
    # Slowdown: each tile and the calibration wait (F - 1) x their render time and report F x it.
    assert len(slept) >= 5, "frames 1 and 3, the calibration and frame 4's first tile"
    for reported, wait_s in zip(render_ms, [*slept[:2], slept[3]], strict=True):
        assert reported == pytest.approx(wait_s * 1e3 * SLOWDOWN / (SLOWDOWN - 1.0), rel=1e-4)
    scene = load_scene("builtin:spheres")
    renderer = TileRenderer(ctx, scene, BACKGROUND)
    reference = renderer.render_tile(Camera.from_json(CAMERA), SIZE, Rect(0, 0, *SIZE)).pixels
    posed = renderer.render_frame(Camera.from_json(CAMERA), SIZE, scene.state_at(0.0, MOVED)).pixels
    renderer.release()
    assert np.array_equal(stitched, reference), "the tiles do not compose the node's own full frame"
    assert np.array_equal(moved, posed), "the tiles of a frame with a state compose that state's frame"
    assert not np.array_equal(moved, reference)
