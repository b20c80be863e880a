"""A render node gives up a point cloud's tile when its frame is cancelled (issue 36): a still's
sample of every point in view stops between two pieces of its draw and is answered with
``tiles_dropped``, and the next frame's tile is drawn at once. A node holds a cloud (and draws it)
once its coarse levels are on the GL side; the rest follows between tiles. A cloud's entry in the
cache is opened by the node itself, checked in the order it is uploaded (rebuilt when its first
blocks fail; a later block that fails is never drawn)."""

from __future__ import annotations

import asyncio
import itertools
import json
import threading
from pathlib import Path

import numpy as np
import pytest
from websockets.asyncio.server import serve

from node.client import NodeClient
from node.gl import point_renderer, worker
from node.gl.point_renderer import PointRenderer
from node.gl.worker import GLWorker
from node.scene import cache, point_cache
from node.scene.cache_folder import CacheFolder
from node.scene.ingest import read_scene
from node.scene.mesh import SceneError
from node.scene.read_process import ready_entry
from node.settings import NodeSettings
from tessera.geometry import Camera, Rect
from tessera.wire.messages import LoadScene
from tessera.wire.protocol import unpack_tile
from tests.conftest import seconds
from tests.test_node_client import FakeCoordinator, receive, receive_json, send

pytestmark = pytest.mark.gl

POINTS = 600_000
CAMERA = {"eye": [-60.0, -140.0, 90.0], "target": [100.0, 100.0, 0.0], "up": [0, 0, 1], "fovy_deg": 50}


def write_points(path: Path) -> Path:
    """A binary PLY of :data:`POINTS` vertices and no faces (a point cloud), 200 m a side."""
    rng = np.random.default_rng(5)
    xyz = np.stack([rng.uniform(0.0, 200.0, POINTS), rng.uniform(0.0, 200.0, POINTS),
                    rng.normal(0.0, 2.0, POINTS)], axis=1).astype("<f4")
    path.write_bytes(f"ply\nformat binary_little_endian 1.0\nelement vertex {POINTS}\nproperty float x\n"
                     "property float y\nproperty float z\nend_header\n".encode() + xyz.tobytes())
    return path


def render(frame: int, size: tuple[int, int], budget: int | None) -> dict:
    return {"type": "render", "frame": frame, "camera": CAMERA, "size": list(size), "codec": "png",
            "point_budget": budget, "tiles": [{"tile": 0, "rect": [0, 0, *size]}]}


async def cancel_a_still_sample(coordinator: FakeCoordinator, cloud: Path) -> list:
    """Frame 1 (a small budget) then frame 2 (every point); frame 2 is cancelled once frame 1's
    tile is back (the node draws frame 2 by then) and frame 3 asked for: what the node sent after
    frame 1's tile, in order."""
    ws = await coordinator.accept()
    assert (await receive_json(ws))["type"] == "hello"
    await send(ws, type="welcome", node_id=1)
    await send(ws, type="load_scene", scene=str(cloud))
    while (message := await receive_json(ws))["type"] != "scene_ready":
        assert message["type"] in ("scene_progress", "levels_ready"), message
    await ws.send(json.dumps(render(1, (64, 48), 2_000)))
    await ws.send(json.dumps(render(2, (1280, 720), None)))
    assert unpack_tile(await receive(ws))[0].frame_id == 1
    await send(ws, type="cancel", frames=[2])
    await ws.send(json.dumps(render(3, (64, 48), 2_000)))
    after = []
    while not after or not isinstance(after[-1], tuple) or after[-1][0] != 3:
        message = await receive(ws)
        after.append(unpack_tile(message)[0].frame_id if isinstance(message, bytes) else json.loads(message))
        if isinstance(after[-1], int):
            after[-1] = (after[-1], "tile")
    return after


def test_a_cancelled_still_sample_is_given_up_between_pieces(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(point_renderer, "PIECE_POINTS", 5_000)
    cloud = write_points(tmp_path / "cloud.ply")

    async def run() -> tuple[list, int]:
        coordinator = FakeCoordinator()
        async with serve(coordinator.handler, "127.0.0.1", 0) as server:
            port = server.sockets[0].getsockname()[1]
            settings = NodeSettings(coordinator=f"ws://127.0.0.1:{port}/ws/node", name="points",
                                    scene_cache_dir=tmp_path / "cache")
            node = NodeClient(settings)
            stop = asyncio.Event()
            task = asyncio.create_task(node.run(stop))
            try:
                after = await asyncio.wait_for(cancel_a_still_sample(coordinator, cloud), seconds(120))
            finally:
                stop.set()
                await asyncio.wait_for(task, seconds(30))
        return after, node.protocol.tiles_dropped

    after, dropped = asyncio.run(run())
    kinds = [m if isinstance(m, tuple) else (m.get("frame"), m["type"]) for m in after]
    assert (2, "tile") not in kinds, f"frame 2 was cancelled while it was drawn: no tile of it, got {kinds}"
    assert kinds.index((2, "tiles_dropped")) < kinds.index((3, "tile")), kinds
    assert next(m for m in after if isinstance(m, dict) and m["type"] == "tiles_dropped")["tiles"] == [0]
    assert dropped == 1


def test_a_cloud_is_held_once_its_coarse_levels_are_uploaded_and_the_rest_follows(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The GL worker answers a cloud's load with its first 50 000 points uploaded; the other steps
    (held back here until the test lets them go) follow on the GL thread, between tiles."""
    monkeypatch.setattr(worker, "FIRST_UPLOAD_POINTS", 50_000)
    monkeypatch.setattr(point_renderer, "UPLOAD_STEP_POINTS", 100_000)
    gate = threading.Event()
    step = PointRenderer.upload_step

    def gated(renderer: PointRenderer, points: int | None = None) -> bool:
        assert gate.wait(seconds(60))
        return step(renderer, points)

    monkeypatch.setattr(PointRenderer, "upload_step", gated)
    spec = str(write_points(tmp_path / "cloud.ply"))
    camera = Camera(tuple(CAMERA["eye"]), tuple(CAMERA["target"]), (0.0, 0.0, 1.0), 50.0)

    async def run() -> tuple[int, int, int, bool]:
        gl = GLWorker()
        await gl.start()
        try:
            loaded = await gl.load(LoadScene(scene=spec), lambda fraction, message: None)
            held = loaded.scene.point_count
            renderer = gl._scenes.find(spec).renderer
            assert isinstance(renderer, PointRenderer)
            uploaded = renderer.uploaded
            gate.set()
            tile = await gl.render(camera, (64, 48), Rect(0, 0, 64, 48), 0, points=(POINTS, None))
            while gl._uploads:
                await asyncio.sleep(0.01)
            return held, uploaded, tile.points, renderer.complete
        finally:
            gate.set()
            await asyncio.to_thread(gl.close)

    held, uploaded, points, complete = asyncio.run(run())
    assert (held, uploaded) == (POINTS, 50_000), "held with its first points on the GL side"
    assert points > 0 and complete, "drawn, then the rest uploaded"


def test_a_cloud_in_the_cache_is_opened_by_the_node_and_a_corrupt_one_built_again(tmp_path: Path) -> None:
    """After a restart (the digest remembered, the entry there) a node opens a cloud's entry itself,
    no reader process started, its CRCs checked beside the upload; an entry whose bytes changed is
    built again before it is held, and drawn as the file is."""
    spec = str(write_points(tmp_path / "cloud.ply"))
    folder = CacheFolder(tmp_path / "cache")
    assert ready_entry(spec, 4096, None, folder) is None, "nothing built yet"
    entry = read_scene(spec, spec, 4096, None, lambda fraction, message: None, folder)
    assert ready_entry(spec, 4096, None, folder) == entry
    camera = Camera(tuple(CAMERA["eye"]), tuple(CAMERA["target"]), (0.0, 0.0, 1.0), 50.0)

    async def drawn() -> tuple[np.ndarray, list[str]]:
        messages: list[str] = []
        gl = GLWorker(cache=folder)
        await gl.start()
        try:
            await gl.load(LoadScene(scene=spec), lambda fraction, message: messages.append(message))
            tile = await gl.render(camera, (64, 48), Rect(0, 0, 64, 48), 0, points=(None, None))
            return tile.pixels, messages
        finally:
            await asyncio.to_thread(gl.close)

    clean, messages = asyncio.run(drawn())
    assert not any(m.startswith("reading") for m in messages), messages
    positions = np.load(entry / "positions.npy", mmap_mode="r+")
    positions[::50, 0] += 30.0
    positions.flush()
    del positions
    assert ready_entry(spec, 4096, None, folder) is None, "the entry fails its check"
    again, messages = asyncio.run(drawn())
    assert any(m.startswith("reading") for m in messages), "the entry was built again"
    assert ready_entry(spec, 4096, None, folder) == entry
    np.testing.assert_array_equal(again, clean)


def test_a_cloud_is_held_once_its_first_blocks_pass_and_no_unchecked_point_is_drawn(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cloud's entry is checked in the order it is uploaded: one whose later block is corrupt is
    held at once (not built again first), its points copied up to that block and no further, the
    entry removed (the next load builds it again); a still, which needs every point, fails."""
    monkeypatch.setattr(cache, "BLOCK_BYTES", 1 << 20)
    monkeypatch.setattr(point_cache, "BLOCK_BYTES", 1 << 20)
    monkeypatch.setattr(worker, "FIRST_UPLOAD_POINTS", 110_000)     # the root node and more
    monkeypatch.setattr(point_renderer, "UPLOAD_STEP_POINTS", 100_000)
    spec = str(write_points(tmp_path / "cloud.ply"))
    folder = CacheFolder(tmp_path / "cache")
    entry = read_scene(spec, spec, 4096, None, lambda fraction, message: None, folder)
    positions = np.load(entry / "positions.npy", mmap_mode="r+")
    bad = (4 << 20) // 12 + 10           # a point of the fifth 1 MiB block of positions
    positions[bad, 0] += 30.0
    positions.flush()
    del positions
    assert list(itertools.islice(point_cache.checked_prefixes(entry), 4)) == [0, 87_381, 174_762, 262_144]
    camera = Camera(tuple(CAMERA["eye"]), tuple(CAMERA["target"]), (0.0, 0.0, 1.0), 50.0)

    async def run() -> tuple[list[str], int, int, str]:
        messages: list[str] = []
        gl = GLWorker(cache=folder)
        await gl.start()
        try:
            await gl.load(LoadScene(scene=spec), lambda fraction, message: messages.append(message))
            renderer = gl._scenes.find(spec).renderer
            assert isinstance(renderer, PointRenderer)
            assert renderer.uploaded == 110_000
            tile = await gl.render(camera, (64, 48), Rect(0, 0, 64, 48), 0, points=(POINTS, None))
            while gl._uploads:
                await asyncio.sleep(0.01)
            with pytest.raises(SceneError) as still:
                await gl.render(camera, (64, 48), Rect(0, 0, 64, 48), 0, points=(None, None))
            return messages, tile.points, renderer.uploaded, str(still.value)
        finally:
            await asyncio.to_thread(gl.close)

    messages, points, uploaded, reason = asyncio.run(run())
    assert not any(m.startswith("reading") for m in messages), "held from the entry, not built again"
    assert points > 0 and 110_000 < uploaded <= (4 << 20) // 12 < bad, f"{uploaded} points copied"
    assert "checksum" in reason
    assert not entry.exists(), "the corrupt entry removed"
