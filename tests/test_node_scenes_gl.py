"""Several scenes on one node (issue 19), on the real GL thread (node/gl/worker.py GLWorker, Mesa
llvmpipe): tiles of two scenes drawn alternately, each equal to that scene drawn alone; a whole
scene beside another's sort-last share; least-recently-used scenes released over the memory
budget; and a scene read in the loader thread while tiles of another keep coming, a mesh step
(issue 33) while the GL thread draws, a built-in scene while a file is fetched."""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bench.mesh_steps import height_field, wave
from node.gl.renderer import TileRenderer
from node.gl.resident import SceneNotLoadedError, estimated_bytes
from node.gl.worker import GLWorker
from node.scene.cache import CacheError, open_entry
from node.scene.cache_folder import CacheFolder
from node.scene.fetch import SceneFetcher
from node.scene.ingest import read_scene
from node.scene.loading import load_scene
from node.scene.mesh import SceneError
from node.scene.shares import keep_share
from tessera.geometry import DEFAULT_BACKGROUND, Camera, Rect, default_camera
from tessera.wire.mesh_update import checked_mesh, pack_mesh
from tessera.wire.messages import DepthRequest, LoadScene, ShareSpec
from tests.conftest import scene_path, seconds

pytestmark = pytest.mark.gl

SIZE = (96, 64)
RECTS = (Rect(0, 0, 40, 64), Rect(40, 0, 56, 64))
SPHERES, CLUSTER, TRAFFIC = "builtin:spheres", "builtin:cluster", "builtin:traffic"
LUCY = "large_scan/stanford_lucy_240k.ply"


def no_progress(fraction: float, message: str) -> None:
    pass


def camera_of(spec: str) -> Camera:
    return default_camera(load_scene(spec).bounds, aspect=SIZE[0] / SIZE[1])


def run_with_worker(body: Callable[[GLWorker], Awaitable[Any]], **options: Any) -> Any:
    """``body`` run with a started GLWorker (its own GL thread and context), closed after."""

    async def main() -> Any:
        worker = GLWorker(**options)
        await worker.start()
        try:
            return await body(worker)
        finally:
            await asyncio.to_thread(worker.close)

    return asyncio.run(main())


def test_tiles_of_two_scenes_drawn_alternately_are_each_the_scene_drawn_alone(ctx):
    specs = (SPHERES, CLUSTER)
    cameras = {spec: camera_of(spec) for spec in specs}

    async def body(worker: GLWorker) -> dict:
        for spec in specs:
            loaded = await worker.load(LoadScene(scene=spec), no_progress)
            assert loaded.scene.name == spec and loaded.share_version is None
        tiles = {}
        for rect in RECTS:
            for spec in specs:
                tiles[spec, rect] = (await worker.render(cameras[spec], SIZE, rect, rect, scene=spec)).pixels
        last = (await worker.render(cameras[CLUSTER], SIZE, RECTS[0], "x")).pixels
        await worker.load(LoadScene(scene=SPHERES), no_progress)
        reloaded = (await worker.render(cameras[SPHERES], SIZE, RECTS[0], "x")).pixels
        assert await worker.held() == [(CLUSTER, None), (SPHERES, None)]
        return {**tiles, "last": last, "reloaded": reloaded}

    drawn = run_with_worker(body)
    for spec in specs:
        renderer = TileRenderer(ctx, load_scene(spec), DEFAULT_BACKGROUND)
        for rect in RECTS:
            alone = renderer.render_tile(cameras[spec], SIZE, rect).pixels
            assert np.array_equal(drawn[spec, rect], alone), f"{spec} {rect}"
        renderer.release()
    assert np.array_equal(drawn["last"], drawn[CLUSTER, RECTS[0]]), "no scene named: the one loaded last"
    assert np.array_equal(drawn["reloaded"], drawn[SPHERES, RECTS[0]]), "a reload makes it the one loaded last"


def test_a_node_holds_one_scene_whole_and_a_share_of_another(ctx):
    share = ShareSpec(version=3, index=0, weights=(1.0, 1.0))
    camera = camera_of(CLUSTER)
    sort_last = DepthRequest(mode="sort-last", share=3)

    async def body(worker: GLWorker) -> tuple:
        await worker.load(LoadScene(scene=SPHERES), no_progress)
        loaded = await worker.load(LoadScene(scene=CLUSTER, share=share), no_progress)
        drawn = await worker.render_depth(camera, SIZE, sort_last, 0, None, scene=CLUSTER)
        whole = await worker.render(camera_of(SPHERES), SIZE, RECTS[1], 1, scene=SPHERES)
        with pytest.raises(SceneNotLoadedError, match=f"share of partition 2 of scene {CLUSTER} asked for; "
                                                      "this node holds 3"):
            await worker.render_depth(camera, SIZE, DepthRequest(mode="sort-last", share=2), 0, None, scene=CLUSTER)
        with pytest.raises(SceneNotLoadedError, match="this node holds the whole scene"):
            await worker.render_depth(camera, SIZE, sort_last, 0, None, scene=SPHERES)
        return loaded, drawn, whole, await worker.held()

    loaded, drawn, whole, held = run_with_worker(body)
    kept = keep_share(load_scene(CLUSTER), share.weights, share.index)
    assert loaded.share_version == 3 and loaded.scene.triangle_count == kept.triangle_count
    assert drawn.share == 3 and drawn.layer is not None and drawn.layer.triangles > 0
    assert whole.triangles > 0
    assert held == [(CLUSTER, (0, (1.0, 1.0))), (SPHERES, None)], "least recently used first"


def test_the_least_recently_used_scenes_are_released_over_the_budget(ctx):
    sizes = {}
    for spec in (SPHERES, TRAFFIC, CLUSTER):
        renderer = TileRenderer(ctx, load_scene(spec))
        sizes[spec] = estimated_bytes(renderer)
        renderer.release()
    budget = sum(sizes.values()) - 1   # two of them fit, not three

    async def body(worker: GLWorker) -> list:
        await worker.load(LoadScene(scene=SPHERES), no_progress)
        await worker.load(LoadScene(scene=TRAFFIC), no_progress)
        await worker.render(camera_of(SPHERES), SIZE, RECTS[0], 0, scene=SPHERES)   # traffic is now the oldest
        await worker.load(LoadScene(scene=CLUSTER), no_progress)
        held = await worker.held()
        with pytest.raises(SceneNotLoadedError, match=f"^scene {TRAFFIC} is not loaded on this node$"):
            await worker.render(camera_of(TRAFFIC), SIZE, RECTS[0], 0, scene=TRAFFIC)
        for spec in (SPHERES, CLUSTER):
            assert (await worker.render(camera_of(spec), SIZE, RECTS[0], 0, scene=spec)).triangles > 0
        await worker.load(LoadScene(scene=TRAFFIC), no_progress)
        return [held, await worker.held()]

    after_cluster, after_traffic = run_with_worker(body, memory_bytes=budget)
    assert after_cluster == [(SPHERES, None), (CLUSTER, None)]
    assert after_traffic == [(CLUSTER, None), (TRAFFIC, None)], "spheres was used before cluster"

    async def tiny(worker: GLWorker) -> list:
        with pytest.raises(SceneError, match="more than this node's --scene-memory-mb 0; serve it in sort-last mode"):
            await worker.load(LoadScene(scene=TRAFFIC), no_progress)
        return await worker.held()

    assert run_with_worker(tiny, memory_bytes=1) == [], "a scene larger than the budget is refused, naming sort-last"


def test_a_scene_holds_its_levels_of_detail_only_within_the_budget(tmp_path, caplog):
    """Levels of detail that would take a scene over ``--scene-memory-mb`` are not built (the log
    says why) nor held: it is drawn at full detail within the budget; with room for them, the
    levels the cache holds are attached and a moving frame draws fewer triangles."""
    path = str(scene_path("bunny/bun_zipper.ply"))
    folder = CacheFolder(tmp_path / "cache")
    camera = camera_of(path)

    async def refused(worker: GLWorker) -> tuple[int, str]:
        loaded = await worker.load(LoadScene(scene=path, levels=True), no_progress)
        return loaded.nbytes, caplog.text   # as the load answers: no build started

    with caplog.at_level("WARNING", logger="tessera.node"):
        alone, logged = run_with_worker(refused, cache=CacheFolder(tmp_path / "tight"), memory_bytes=7 << 18)
    assert alone <= 7 << 18, "the scene fits alone"
    assert f"levels of detail of {path} not held: with them it needs about 2 MB, more than this node's " \
        "--scene-memory-mb 2; it is drawn at full detail" in logged, "no levels built beyond the budget"

    async def built(worker: GLWorker) -> int:
        made: asyncio.Future[Any] = asyncio.get_running_loop().create_future()
        worker.levels_listener = lambda spec, version, tree, scene, groups: made.done() or made.set_result(tree)
        loaded = await worker.load(LoadScene(scene=path, levels=True), no_progress)
        await asyncio.wait_for(made, seconds(120))
        return loaded.nbytes

    scene_bytes = run_with_worker(built, cache=folder)

    async def moving(worker: GLWorker) -> tuple[Any, int, int]:
        loaded = await worker.load(LoadScene(scene=path, levels=True), no_progress)
        coarse = await worker.render(camera, SIZE, Rect(0, 0, *SIZE), 0, scene=path, lod_error_px=4.0)
        full = await worker.render(camera, SIZE, Rect(0, 0, *SIZE), 0, scene=path)
        return loaded, coarse.triangles, full.triangles

    roomy, coarse, full = run_with_worker(moving, cache=folder)
    assert roomy.levels is not None and roomy.nbytes > scene_bytes
    assert 0 < coarse < full, "the levels held draw fewer triangles while moving"
    tight, coarse, full = run_with_worker(moving, cache=folder, memory_bytes=roomy.nbytes - 1)
    assert tight.levels is None and tight.nbytes == tight.held_bytes == scene_bytes
    assert coarse == full > 0, "without its levels the scene is drawn at full detail"


class HeldFetcher(SceneFetcher):
    """A fetcher whose download lasts until the test lets it go."""

    def __init__(self) -> None:
        super().__init__("ws://127.0.0.1:1/ws/node")
        self.started, self.finish = threading.Event(), threading.Event()

    def source(self, spec: str, sha256: str | None, url: str | None, progress: Callable[[float, str], None]) -> str:
        self.started.set()
        assert self.finish.wait(seconds(30))
        return spec


def test_tiles_of_a_scene_held_are_drawn_while_another_is_read():
    fetcher = HeldFetcher()

    async def body(worker: GLWorker) -> tuple:
        await worker.load(LoadScene(scene=SPHERES), no_progress)
        fetcher.finish.clear()
        loading = asyncio.create_task(worker.load(LoadScene(scene=TRAFFIC), no_progress))
        assert await asyncio.to_thread(fetcher.started.wait, seconds(30))
        triangles = [(await worker.render(camera_of(SPHERES), SIZE, rect, 0, scene=SPHERES)).triangles
                     for rect in RECTS]
        with pytest.raises(SceneNotLoadedError, match=f"scene {TRAFFIC} is not loaded"):
            await worker.render(camera_of(TRAFFIC), SIZE, RECTS[0], 0, scene=TRAFFIC)
        waiting = asyncio.create_task(worker.load(LoadScene(scene=TRAFFIC, background=(0.0, 0.0, 0.0)), no_progress))
        assert not loading.done()
        fetcher.finish.set()
        first, second = await loading, await waiting
        return triangles, first, second, await worker.held()

    fetcher.finish.set()
    triangles, first, second, held = run_with_worker(body, fetcher=fetcher)
    assert all(count > 0 for count in triangles), "drawn while the loader thread was busy"
    assert first.scene is second.scene, "a second load of a scene being read waits for it, then reuses it"
    assert held == [(SPHERES, None), (TRAFFIC, None)]


class FileHeldFetcher(HeldFetcher):
    """A fetcher whose download of a file lasts until the test lets it go (built-in scenes pass)."""

    def source(self, spec: str, sha256: str | None, url: str | None, progress: Callable[[float, str], None]) -> str:
        return spec if spec.startswith("builtin:") else super().source(spec, sha256, url, progress)


def test_a_built_in_scene_loads_while_a_file_is_still_fetched():
    """Issue 31: a built-in scene told after a file (the coordinator's default scene after a
    session's big model) loads while the file is still fetched (or ingested), not after it."""
    fetcher = FileHeldFetcher()
    bunny = str(scene_path("bunny/bun_zipper.ply"))

    async def body(worker: GLWorker) -> tuple:
        reading = asyncio.create_task(worker.load(LoadScene(scene=bunny), no_progress))
        assert await asyncio.to_thread(fetcher.started.wait, seconds(30))
        built_in = await asyncio.wait_for(worker.load(LoadScene(scene=SPHERES), no_progress), seconds(20))
        early = reading.done()
        fetcher.finish.set()
        return built_in, early, await reading

    built_in, early, file = run_with_worker(body, fetcher=fetcher)
    assert built_in.scene.name == SPHERES and not early, "the built-in scene was held while the file was fetched"
    assert file.scene.triangle_count > 0


def test_a_mesh_step_is_read_while_the_gl_thread_draws():
    """Issue 33: a mesh step loaded ahead is read (split into chunks, smooth normals) in the loader
    thread while the GL thread is busy with a tile, not after it; only its upload waits."""
    grid, faces = height_field(20_000)
    gate, read = threading.Event(), threading.Event()

    async def body(worker: GLWorker) -> tuple[bool, bool, int]:
        worker.meshes.receive(pack_mesh(checked_mesh(wave(grid, 0.0), faces), scene="mesh:g:1"))
        scene_of = worker.meshes.scene
        worker.meshes.scene = lambda *args: (scene_of(*args), read.set())[0]   # type: ignore[method-assign]
        drawing = asyncio.create_task(worker._call(gate.wait, seconds(30)))   # the GL thread draws a tile
        loading = asyncio.create_task(worker.load(LoadScene(scene="mesh:g:1"), no_progress))
        was_read = await asyncio.to_thread(read.wait, seconds(30))
        held_early = loading.done()
        gate.set()
        loaded = await loading
        await drawing
        return was_read, held_early, loaded.scene.triangle_count

    was_read, held_early, triangles = run_with_worker(body)
    assert was_read, "read while the GL thread was busy"
    assert not held_early and triangles == len(faces), "uploaded once the GL thread was free"


def test_a_big_scan_is_read_while_tiles_of_another_scene_keep_coming():
    """The 240 k-triangle Lucy (about a second to parse alone) loads while a scene held is drawn
    tile after tile: tiles keep coming at about their usual pace, no gap near the load's length."""
    lucy = str(scene_path(LUCY))
    camera = camera_of(CLUSTER)

    async def body(worker: GLWorker) -> tuple[float, list[float]]:
        await worker.load(LoadScene(scene=CLUSTER), no_progress)
        started = time.perf_counter()
        loading = asyncio.create_task(worker.load(LoadScene(scene=lucy), no_progress))
        stamps = [started]
        while not loading.done():
            await worker.render(camera, (320, 180), Rect(0, 0, 320, 180), 0, scene=CLUSTER)
            stamps.append(time.perf_counter())
        assert (await loading).scene.triangle_count == 239_768
        return time.perf_counter() - started, np.diff(stamps).tolist()

    load_s, gaps = run_with_worker(body)
    assert len(gaps) >= 5, f"only {len(gaps)} tiles in a load of {load_s:.2f} s"
    assert max(gaps) < load_s / 3, f"a {max(gaps):.2f} s gap between tiles in a load of {load_s:.2f} s"


def test_an_entry_found_corrupt_while_it_is_uploaded_is_built_again_before_it_is_held(ctx, tmp_path):
    """A node uploads an entry found in the cache while another thread checks its CRCs: one whose
    bytes changed (shapes intact) is released and built again; the scene held and drawn is the file's."""
    path = str(scene_path("bunny/bun_zipper.ply"))
    folder = CacheFolder(tmp_path / "cache")
    entry = read_scene(path, path, 192, None, no_progress, folder)
    assert isinstance(entry, Path)
    camera = default_camera(load_scene(path).bounds, aspect=SIZE[0] / SIZE[1])

    async def drawn(worker: GLWorker) -> tuple[np.ndarray, list[str]]:
        messages: list[str] = []
        await worker.load(LoadScene(scene=path), lambda fraction, message: messages.append(message))
        tile = await worker.render(camera, SIZE, Rect(0, 0, *SIZE), 0, scene=path)
        return tile.pixels, messages

    clean, messages = run_with_worker(drawn, cache=folder)
    assert not any(m.startswith("read") for m in messages), "the entry in the cache was opened"
    vertices = np.load(entry / "vertices.npy", mmap_mode="r+")
    vertices["position"][::40, 0] *= 3.0
    vertices.flush()
    del vertices
    with pytest.raises(CacheError):
        open_entry(entry, path, verify=True)
    again, messages = run_with_worker(drawn, cache=folder)
    assert any(m.startswith("read") for m in messages), "the entry was built again"
    open_entry(entry, path, verify=True)
    assert np.array_equal(again, clean)
