"""The render node's GL thread (:class:`GLWorker`): the one thread that owns the GL context, where
scenes are uploaded and drawn — plain tiles, depth tiles (:mod:`node.gl.depth_layers`) and
calibration renders — for :class:`node.client.NodeClient`, which awaits each call.

A node holds several scenes at once (issue 19: :mod:`node.gl.resident`, within a memory budget) and
draws a tile of whichever a ``render`` names. A scene is made ready — fetched when the node cannot
open it (:mod:`node.scene.fetch`), then ingested once into the scene cache (issue 31: read, split
into chunks, packed, written; a sort-last share written as an entry of its own,
:mod:`node.scene.ingest`) and mapped — off the GL thread, so the seconds a big scan takes never hold
back tiles of the scenes already held: a loader thread fetches and opens it (a file in a thread of
its own, so that a built-in scene never waits behind one), a large file ingested
in a child process of lower CPU priority (:mod:`node.scene.read_process`: a thread would hold the
GIL the GL thread needs). Only its upload runs on the GL thread, between two tiles; a point cloud
is held once its coarse levels are uploaded, the rest copied a step at a time between tiles
(:data:`node.gl.point_renderer.FIRST_UPLOAD_POINTS`).

A scene (or share) whose GPU buffers exceed the memory budget is refused with the reason, naming
sort-last as the mode that serves it (its buffers are all host memory on llvmpipe); its levels of
detail are held only where the scene with them fits the budget (else it is drawn at full detail).
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import time
from collections.abc import Callable, Hashable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import moderngl

from node.culling.switch import CullMode
from node.gl.context import create_gl_context, renderer_string
from node.gl.depth_layers import PlanningScene, as_depth_layer, live_plan, render_plan
from node.gl.point_renderer import FIRST_UPLOAD_POINTS, PointRenderer
from node.gl.renderer import BlendedFragments, RenderedTile, TileRenderer
from node.gl.resident import ResidentScene, ResidentScenes, SceneKey, estimated_bytes, scene_key
from node.gl.shading import ShadingOptions
from node.gl.shared import SharedGL
from node.gl.view_tools import ViewTools
from node.scene.cache import CacheError, open_entry, remove_entry
from node.scene.cache_folder import CacheFolder
from node.scene.data import SceneData
from node.scene.fetch import SceneFetcher
from node.scene.ingest import kept_group_levels, open_cached, read_scene
from node.scene.loading import BUILTIN_PREFIX, ProgressCallback
from node.scene.lod import BYTES_PER_TRIANGLE as LEVELS_BYTES_PER_TRIANGLE
from node.scene.lod import LOD_FORMAT, GroupLevels, LodTree, lod_name, read_lod
from node.scene.mesh import SceneError
from node.scene.mesh_store import MeshStore
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.scene.point_cache import PointCheck, is_points_entry, open_points_entry
from node.scene.points import PointCloud
from node.scene.read_process import READ_IN_PROCESS_BYTES, SceneReaderProcess, reads_in_process, ready_entry
from node.scene.shares import keep_share
from node.settings import DEFAULT_SCENE_MEMORY_MB
from tessera.compositing.layers import BlendLayer, DepthLayer
from tessera.geometry import DEFAULT_BACKGROUND, Camera, Rect
from tessera.scene.state import SceneState
from tessera.scheduling.refinement import Subsample
from tessera.tools.picking import PickHit
from tessera.wire.mesh_update import is_mesh_spec, mesh_group
from tessera.wire.messages import DepthRequest, LoadScene
from tessera.wire.pick_messages import Pick

log = logging.getLogger("tessera.node")

#: A frame's point cloud settings (issue 36): its point budget (None: a still's), smallest splat
#: side in px and a still's spacing on screen in px (0: every point in view) (None: the defaults).
PointStyle = tuple[int | None, float | None, float | None]


@dataclass(frozen=True, slots=True)
class DepthRender:
    """A depth tile as drawn: its ``layer`` (None: nothing of it in view), its ``core`` (sent
    without depth; None: none), its blended fragments drawn apart (sort-last; None: none), the
    ms spent choosing its chunks and the data partition version of the share drawn (0: the whole
    scene)."""

    layer: RenderedTile | None
    core: Rect | None
    blend: BlendedFragments | None
    plan_ms: float
    share: int = 0

    def depth_layer(self) -> DepthLayer | None:
        return None if self.layer is None else as_depth_layer(self.layer, 0)

    def blend_layer(self) -> BlendLayer | None:
        if self.blend is None or self.layer is None or not self.blend.depth.shape[0]:
            return None
        return BlendLayer(self.layer.rect, self.blend.color, self.blend.alpha, self.blend.depth, 0)

    @property
    def times(self) -> tuple[float, float]:
        """(render ms with the planning, read-back ms)."""
        blend = self.blend
        render = self.plan_ms + (0.0 if self.layer is None else self.layer.render_ms)
        readback = 0.0 if self.layer is None else self.layer.readback_ms
        return (render + (blend.render_ms if blend else 0.0), readback + (blend.readback_ms if blend else 0.0))

    def stats(self) -> dict[str, Any]:
        """Its ``tile_sent`` counters before encoding (the encoder adds the byte counts)."""
        stats: dict[str, Any] = {"triangles": 0} if self.layer is None else self.layer.stats()
        stats["triangles"] += 0 if self.blend is None else self.blend.triangles
        stats["plan_ms"] = round(self.plan_ms, 4)
        return stats


@dataclass(frozen=True, slots=True)
class LoadedScene:
    """A scene held, as a load answers: its data, the partition version of its share (None: whole),
    the bytes it is counted for and those of every scene held (:mod:`node.gl.resident`)."""

    scene: SceneData | PointCloud
    share_version: int | None
    nbytes: int = 0
    held_bytes: int = 0
    #: Its levels of detail when it has them already (a scene held again, or found in the cache).
    levels: LodTree | None = None
    #: Its primitive groups' levels (:func:`node.scene.lod.group_levels`) when they were worked out
    #: with the levels (None: the caller works them out).
    group_levels: GroupLevels | None = None


class GLWorker:
    """The one thread that owns the GL context, and the loader thread: scenes are read (split into
    chunks of at most ``face_limit`` faces; in sort-last only a share kept; fetched by ``fetcher``
    when the node cannot open them, None: never) by the loader thread — files of at least
    ``read_in_process_bytes`` in the scene reader process —, then uploaded and drawn (with
    ``culling``) on the GL thread, which holds them within ``memory_bytes``
    (:class:`node.gl.resident.ResidentScenes`).

    The scenes held survive reconnects; asking for a scene (and share) held again reuses it.
    """

    def __init__(self, culling: CullMode = CullMode.AUTO, face_limit: int = DEFAULT_FACE_LIMIT,
                 memory_bytes: int = DEFAULT_SCENE_MEMORY_MB << 20, fetcher: SceneFetcher | None = None,
                 read_in_process_bytes: int = READ_IN_PROCESS_BYTES,
                 shading: ShadingOptions = ShadingOptions(), cache: CacheFolder | None = None) -> None:
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="tessera-gl")
        self._loader = ThreadPoolExecutor(1, thread_name_prefix="tessera-load")
        #: Files are fetched and ingested in a thread of their own: a built-in scene or a mesh sent as
        #: arrays (read from memory) never waits behind the seconds a big file takes (issue 31: the
        #: default scene queued behind a 100M-triangle ingest was ready 45-86 s after the node started).
        self._file_loader = ThreadPoolExecutor(1, thread_name_prefix="tessera-load-file")
        self._checker = ThreadPoolExecutor(1, thread_name_prefix="tessera-check")
        self._reader = SceneReaderProcess()
        #: Levels of detail are built in a reader of their own, so a scene's load never waits for them.
        self._levels_loader = ThreadPoolExecutor(1, thread_name_prefix="tessera-levels")
        self._levels_reader = SceneReaderProcess()
        self._levels_tasks: set[asyncio.Task[None]] = set()
        self._levels_building: set[SceneKey] = set()
        self._uploads: set[asyncio.Task[None]] = set()
        self._closing = False   # close() kills the readers: a read they fail then is the stop, not a fault
        #: Told (on the event loop) of each scene whose levels of detail were attached: its spec,
        #: share version (None: whole), levels, scene and its primitive groups' levels (None: not worked out).
        self.levels_listener: Callable[[str, int | None, LodTree, SceneData, GroupLevels | None], None] | None = None
        self.read_in_process_bytes = read_in_process_bytes
        self._ctx: moderngl.Context | None = None
        #: The framebuffers and lighting every scene's renderer shares (:class:`node.gl.shared.SharedGL`).
        self._shared: SharedGL | None = None
        self._scenes = ResidentScenes(memory_bytes)
        self._reading: dict[SceneKey, asyncio.Task[LoadedScene]] = {}
        self.culling, self.face_limit, self.fetcher = culling, face_limit, fetcher
        self.shading, self.cache = shading, cache
        #: Meshes the coordinator sent as arrays (issue 33), read by loads of their ``mesh:`` specs.
        self.meshes = MeshStore()

    async def _call(self, function: Callable[..., Any], *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._executor, function, *args)

    async def start(self) -> str:
        """Create the context; returns the GL renderer string. Raises GLUnavailableError."""
        return await self._call(self._start)

    def _start(self) -> str:
        self._ctx = create_gl_context()
        self._shared = SharedGL(self._ctx)
        return renderer_string(self._ctx)

    async def load(self, request: LoadScene, progress: ProgressCallback) -> LoadedScene:
        """Load ``request``'s scene (only its share, if any) beside those held, or reuse it when
        held (a load of it under way, asked for on an earlier connection, is waited for); raises
        SceneError, or the upload's GL error. A scene not held starts reading at once, also while the
        GL thread draws a tile (a mesh step loaded ahead: issue 33)."""
        key = scene_key(request.scene, request.share)
        while True:
            loaded = await self._call(self._reuse, key, request) if self._scenes.holds(key) else None
            if loaded is not None:
                if request.levels and loaded.levels is None:
                    self._build_levels(key)
                return loaded
            reading = self._reading.get(key)
            if reading is None:
                reading = asyncio.get_running_loop().create_task(self._read_and_upload(key, request, progress))
                self._reading[key] = reading
                reading.add_done_callback(lambda task: self._read_done(key, task))
                return await asyncio.shield(reading)
            await asyncio.shield(reading)

    def _read_done(self, key: SceneKey, task: asyncio.Task[LoadedScene]) -> None:
        """Forget the load of ``key`` once done; its error reached whoever awaited it (none: dropped)."""
        self._reading.pop(key, None)
        if not task.cancelled():
            task.exception()

    async def _read_and_upload(self, key: SceneKey, request: LoadScene, progress: ProgressCallback) -> LoadedScene:
        """Read, upload and hold the scene; levels of detail the cache holds already are attached
        before it is answered (its first frame may use them), others built in the background."""
        loop = asyncio.get_running_loop()
        reader = self._loader if is_mesh_spec(request.scene) or request.scene.startswith(BUILTIN_PREFIX) \
            else self._file_loader
        scene, entry, unchecked = await loop.run_in_executor(reader, self._read, request, progress, False)
        # An entry found in the cache is checked (its CRCs) in a thread of its own while the GL thread
        # uploads it, and the levels the cache holds are read and checked in the loader thread; the
        # scene is held (drawn) only once its entry passed. A point cloud's entry is checked in the
        # order it is uploaded: held once its node table and first points passed, the rest copied
        # as it passes (issue 36: the first frame of 100M points waited for 1.5 GB of CRCs).
        points_check = None
        if unchecked and entry is not None and isinstance(scene, PointCloud):
            points_check = PointCheck(entry)
            if not await self._first_points_checked(points_check, scene.point_count):
                log.warning("scene cache entry %s fails its check (%s); building it again", entry, points_check.failed)
                scene, entry, _ = await loop.run_in_executor(reader, self._read, request, progress, True)
                points_check = None
        check = loop.run_in_executor(self._checker, self._check, entry, scene.name) \
            if unchecked and entry is not None and not isinstance(scene, PointCloud) else None
        levels = loop.run_in_executor(self._loader, self._cached_levels, entry, scene) \
            if request.levels and entry is not None and isinstance(scene, SceneData) else None
        try:
            made = await self._call(self._upload, key, request, scene, entry, progress, points_check)
            if check is not None and not await check:
                await self._call(made.renderer.release)
                log.warning("scene cache entry %s fails its check; building it again", entry)
                scene, entry, _ = await loop.run_in_executor(reader, self._read, request, progress, True)
                if levels is not None:
                    levels = loop.run_in_executor(self._loader, self._cached_levels, entry, scene) \
                        if entry is not None and isinstance(scene, SceneData) else None
                made = await self._call(self._upload, key, request, scene, entry, progress)
            loaded: LoadedScene = await self._call(self._hold, made)
            if isinstance(made.renderer, PointRenderer) and not made.renderer.complete:
                task = loop.create_task(self._upload_rest(key, made.renderer, entry))
                self._uploads.add(task)
                task.add_done_callback(self._uploads.discard)
        except BaseException:
            for pending in (check, levels):
                if pending is not None:
                    pending.add_done_callback(lambda done: done.cancelled() or done.exception())
            raise
        if request.levels:
            found = None if levels is None else await levels
            held = None if found is None else await self._call(self._attach_levels, key, found[0])
            if found is None:
                self._build_levels(key)
            elif held is not None:
                loaded = dataclasses.replace(loaded, nbytes=held.nbytes, held_bytes=self._scenes.total_bytes,
                                             levels=found[0], group_levels=found[1])
        return loaded

    async def _first_points_checked(self, check: PointCheck, count: int) -> bool:
        """Start ``check`` in the checking thread; whether the node table and the points a node
        copies first (:data:`FIRST_UPLOAD_POINTS`, of ``count``) passed."""
        loop = asyncio.get_running_loop()
        running = loop.run_in_executor(self._checker, check.run)
        running.add_done_callback(lambda done: done.cancelled() or done.exception())
        return bool(await loop.run_in_executor(None, check.wait, min(FIRST_UPLOAD_POINTS, count)))

    async def _upload_rest(self, key: SceneKey, renderer: PointRenderer, entry: Path | None) -> None:
        """Copy the points of the cloud held as ``key`` not on the GL side yet, a step at a time,
        each a call of its own on the GL thread (tiles are drawn between two), each once its points
        passed their check (a check that fails stops the copy, the entry ``entry`` removed: moving
        frames draw the points copied, a still fails, the next load builds it again); until the
        scene is released or the worker closes."""
        started = time.perf_counter()
        loop, check = asyncio.get_running_loop(), renderer.checked
        try:
            while not self._closing:
                if check is not None and not await loop.run_in_executor(None, check.wait, renderer.uploaded + 1):
                    log.warning("scene cache entry %s fails its check (%s): %d of %d points drawn, the entry "
                                "removed", entry, check.failed, renderer.uploaded, renderer.scene.point_count)
                    if entry is not None:
                        remove_entry(entry)
                    return
                if not await self._call(self._upload_step, key, renderer):
                    break
        except RuntimeError:   # the GL thread stopped (close)
            if not self._closing:
                raise
        if renderer.complete:
            log.info("%s: %d points on the GL side %.1f s after its first frame could be drawn", key[0],
                     renderer.scene.point_count, time.perf_counter() - started)

    def _upload_step(self, key: SceneKey, renderer: PointRenderer) -> bool:
        """On the GL thread: the next step of ``renderer``'s upload; whether more is to come (False
        also when the scene held as ``key`` is no longer that renderer's)."""
        held = self._scenes.held(key)
        return held is not None and held.renderer is renderer and not renderer.upload_step()

    def _check(self, entry: Path, name: str) -> bool:
        """In the checking thread: whether every array of cache entry ``entry`` (a mesh's or a point
        cloud's) passes its CRCs."""
        try:
            (open_points_entry if is_points_entry(entry) else open_entry)(entry, name, verify=True)
        except CacheError:
            return False
        return True

    def _cached_levels(self, entry: Path, scene: SceneData) -> tuple[LodTree, GroupLevels] | None:
        """In the loader thread: the levels of detail of cache entry ``entry`` (``scene``) and its
        primitive groups' levels when the cache holds them and they pass their check; None
        otherwise (then they are built, or rebuilt, apart)."""
        cache = self.cache
        found = None if cache is None else cache.existing(lod_name(entry.name), LOD_FORMAT)
        if cache is None or found is None:
            return None
        try:
            tree = read_lod(found, verify=True)
        except CacheError:
            return None
        if not tree.node_count:
            return None
        return tree, kept_group_levels(cache, found, tree, scene)

    def _build_levels(self, key: SceneKey) -> None:
        """Start building the levels of detail of the scene held as ``key`` (from its cache entry;
        nothing for a scene read into memory, when its levels are being built already, or when they
        would not fit the budget)."""
        held = self._scenes.held(key)
        if held is None or held.entry is None or self.cache is None or key in self._levels_building \
                or self._scenes.levels_refused(key) \
                or isinstance(held.renderer, PointRenderer):   # a point cloud's octree is its levels
            return
        expected = held.nbytes + LEVELS_BYTES_PER_TRIANGLE * held.renderer.scene.triangle_count
        if not self._scenes.levels_fit(key, expected):
            return
        self._levels_building.add(key)
        task = asyncio.get_running_loop().create_task(self._levels(key, held.entry))
        self._levels_tasks.add(task)
        task.add_done_callback(self._levels_tasks.discard)
        task.add_done_callback(lambda _: self._levels_building.discard(key))

    async def _levels(self, key: SceneKey, entry: Path) -> None:
        """Build (or find) the levels of detail of the scene held as ``key`` (cache entry ``entry``)
        in the levels reader, then attach them on the GL thread; a failure is logged, the scene
        stays drawn at full detail."""
        assert self.cache is not None
        started = time.perf_counter()
        try:
            path = await asyncio.get_running_loop().run_in_executor(
                self._levels_loader, self._levels_reader.levels, entry, self.cache, lambda fraction, message: None)
            tree = None if path is None else read_lod(path, verify=False)
            shown = self._scenes.held(key)
            scene = None if shown is None else shown.renderer.scene
            groups = None if tree is None or path is None or not isinstance(scene, SceneData) else \
                await asyncio.get_running_loop().run_in_executor(self._levels_loader, kept_group_levels, self.cache,
                                                                 path, tree, scene)
        except (SceneError, CacheError) as exc:
            if self._closing:
                log.info("levels of detail of %s: not built, the node is stopping", key[0])
            else:
                log.warning("levels of detail of %s failed: %s", key[0], exc)
            return
        if tree is not None:
            held = await self._call(self._attach_levels, key, tree)
            if held is not None:
                log.info("levels of detail of %s: %d nodes in %.1f s", key[0], tree.node_count,
                         time.perf_counter() - started)
                if self.levels_listener is not None:
                    self.levels_listener(key[0], held.share_version, tree, held.renderer.scene, groups)

    def _attach_levels(self, key: SceneKey, tree: LodTree) -> ResidentScene | None:
        """On the GL thread: give the scene held as ``key`` its levels, releasing the least recently
        used others over the budget; None when it is no longer held, or when with its levels it
        would need more than the budget (it stays drawn at full detail, logged)."""
        held = self._scenes.held(key)
        if held is None or not isinstance(held.renderer, TileRenderer):
            return held
        if not self._scenes.levels_fit(key, held.nbytes + tree.nbytes):
            return None
        held.renderer.attach_lod(tree)
        held.nbytes = estimated_bytes(held.renderer)
        for spec, _ in self._scenes.release_over_budget(key):
            log.info("scene %s released: the scenes held exceed --scene-memory-mb %.0f", spec,
                     self._scenes.budget_bytes / (1 << 20))
        return held

    def _read(self, request: LoadScene, progress: ProgressCallback,
              verify: bool) -> tuple[SceneData | PointCloud, Path | None, bool]:
        """In the loader thread: fetch (if need be), then ingest or open its cache entry (here, or a
        large file in the scene reader process) and map it; refuse it when it exceeds the budget.
        The scene, its cache entry (None: read into memory), and whether that entry was found in
        the cache and not checked (``verify`` False: the caller checks it, :meth:`_check`)."""
        spec, share = request.scene, request.share
        if is_mesh_spec(spec):   # issue 33: from memory, no cache entry
            mesh = self.meshes.scene(spec, self.face_limit)
            return (mesh if share is None else keep_share(mesh, share.weights, share.index)), None, False
        source = spec if self.fetcher is None else self.fetcher.source(spec, request.sha256, request.url, progress)
        known = request.sha256 if source != spec else None
        made: SceneData | PointCloud | Path | None = ready_entry(source, self.face_limit, share, self.cache, known,
                                                                 verify)
        unchecked = made is not None and not verify
        if made is None:
            read = self._reader.read if reads_in_process(source, self.read_in_process_bytes) else read_scene
            made = read(source, spec, self.face_limit, share, progress, self.cache, known)
        scene = open_cached(made, spec)
        needed, budget = scene.gpu_bytes + scene.nbytes, self._scenes.budget_bytes
        if needed > budget:
            mode = "serve it in sort-last mode (coordinator --mode sort-last), where each node holds a share" \
                if share is None else "add nodes, so that each share is smaller"
            raise SceneError(f"{spec}: needs {needed / (1 << 20):.0f} MB, more than this node's --scene-memory-mb "
                             f"{budget / (1 << 20):.0f}; {mode}")
        return scene, made if isinstance(made, Path) else None, unchecked

    def _upload(self, key: SceneKey, request: LoadScene, scene: SceneData | PointCloud, entry: Path | None,
                progress: ProgressCallback, points_check: PointCheck | None = None) -> ResidentScene:
        """On the GL thread: upload ``scene`` (not held yet: :meth:`_hold`); a point cloud only as far
        as ``points_check`` passed its entry (None: checked, or read into memory)."""
        assert self._ctx is not None
        if is_mesh_spec(key[0]) and not self.meshes.live(key[0]):
            raise SceneError(f"{key[0]}: superseded by a newer mesh while it was read")
        share = request.share
        background = DEFAULT_BACKGROUND if request.background is None else request.background
        renderer: TileRenderer | PointRenderer
        if isinstance(scene, PointCloud):
            progress(0.9, f"uploading {scene.point_count} points in {scene.nodes.count} octree nodes")
            renderer = PointRenderer(self._ctx, scene, background, first_points=FIRST_UPLOAD_POINTS,
                                     checked=points_check)
            planning = None
        else:
            progress(0.9, f"uploading {scene.triangle_count} triangles in {scene.chunks.chunk_count} chunks")
            renderer = TileRenderer(self._ctx, scene, background, culling=self.culling, packed=scene.geometry,
                                    shading=self.shading, shared=self._shared)
            planning = PlanningScene.of(scene, renderer.culler.bvh)
        version = None if share is None else share.version
        return ResidentScene(key, renderer, planning, version, estimated_bytes(renderer), entry=entry)

    def _hold(self, held: ResidentScene) -> LoadedScene:
        """On the GL thread: hold the scene uploaded as ``held``, release the least recently used
        others over budget."""
        key = held.key
        if is_mesh_spec(key[0]):   # a session's newer mesh: those of its group not kept are drawn no more
            self._scenes.release(lambda other: is_mesh_spec(other[0]) and mesh_group(other[0]) == mesh_group(key[0])
                                 and other[0] != key[0] and not self.meshes.live(other[0]))
        for spec, _ in self._scenes.add(held):
            log.info("scene %s released: the scenes held exceed --scene-memory-mb %.0f", spec,
                     self._scenes.budget_bytes / (1 << 20))
        return LoadedScene(held.renderer.scene, held.share_version, held.nbytes, self._scenes.total_bytes)

    def _reuse(self, key: SceneKey, request: LoadScene) -> LoadedScene | None:
        """The scene of ``key`` if held, with ``request``'s background and share version; else None."""
        held = self._scenes.reloaded(key)
        if held is None:
            return None
        if request.background is not None:
            held.renderer.background = request.background
        held.share_version = None if request.share is None else request.share.version
        levels = None if held.renderer.lod is None else held.renderer.lod.tree
        return LoadedScene(held.renderer.scene, held.share_version, held.nbytes, self._scenes.total_bytes, levels)

    async def held(self) -> list[SceneKey]:
        """The keys of the scenes held, least recently used first."""
        keys: list[SceneKey] = await self._call(self._scenes.keys)
        return keys

    async def render(self, camera: Camera, size: tuple[int, int], rect: Rect, slot: Hashable,
                     state: SceneState | None = None, scene: str | None = None,
                     subsample: Subsample | None = None, tools: ViewTools | None = None,
                     lod_error_px: float = 0.0, window: Rect | None = None,
                     points: PointStyle = (None, None, None), stop: Callable[[], bool] | None = None) -> RenderedTile:
        """Render ``rect`` of ``scene`` (a spec; None: the scene loaded last) in scene ``state``
        (None: the base pose), as ``subsample`` of a still (None: a plain frame, at the levels of
        detail within ``lod_error_px``), with the frame's ``tools`` (clip, highlight; None: none), in
        ``window`` (a poster's; None: the whole frame); ``slot`` (the tile id) keys the tile's hybrid
        culling switch; a point cloud within the ``points`` budget, its splats at least the size
        given (:data:`PointStyle`), given up between two pieces once ``stop()`` is true (DrawStopped;
        a mesh's tile is drawn whole). Raises SceneNotLoadedError for a scene not held."""
        return await self._call(self._render, camera, size, rect, slot, state, scene, subsample, tools, lod_error_px,
                                window, points, stop)

    def _render(self, camera: Camera, size: tuple[int, int], rect: Rect, slot: Hashable,
                state: SceneState | None, scene: str | None, subsample: Subsample | None,
                tools: ViewTools | None, lod_error_px: float, window: Rect | None,
                points: PointStyle = (None, None, None), stop: Callable[[], bool] | None = None) -> RenderedTile:
        renderer = self._scenes.find(scene).renderer
        renderer.use_tools(tools)
        if isinstance(renderer, PointRenderer):
            if window is not None:
                raise ValueError("pictures over a window's side are not drawn of point clouds")
            renderer.style(*points[1:])
            return renderer.render_tile(camera, size, rect, subsample=subsample, point_budget=points[0], stop=stop)
        return renderer.render_tile(camera, size, rect, slot, state=state, subsample=subsample,
                                    lod_error_px=lod_error_px, window=window)

    async def render_depth(self, camera: Camera, size: tuple[int, int], request: DepthRequest, tile_id: int,
                           state: SceneState | None, scene: str | None = None,
                           subsample: Subsample | None = None, tools: ViewTools | None = None,
                           lod_error_px: float = 0.0, points: PointStyle = (None, None, None),
                           area: Rect | None = None, window: Rect | None = None,
                           stop: Callable[[], bool] | None = None) -> DepthRender:
        """Tile ``tile_id`` of a depth ``request`` of ``scene`` (None: the scene loaded last) in
        scene ``state`` as a depth layer; sort-last draws the share of the request's partition
        version over the tile's ``area`` (None: the whole frame; a poster's piece, in its
        ``window``); ``subsample`` and ``tools`` as :meth:`render`'s; sort-last layers at the levels of
        detail within ``lod_error_px`` (hybrid layers at full detail: a coarse node spans chunks
        other tiles own); a point cloud's sort-last layer within the ``points`` budget, unshaded (the
        coordinator shades the merged frame; ``stop`` as :meth:`render`'s). Raises SceneNotLoadedError
        for a scene or share not held."""
        return await self._call(self._render_depth, camera, size, request, tile_id, state, scene, subsample, tools,
                                lod_error_px, points, area, window, stop)

    def _render_depth(self, camera: Camera, size: tuple[int, int], request: DepthRequest, tile_id: int,
                      state: SceneState | None, scene: str | None, subsample: Subsample | None,
                      tools: ViewTools | None, lod_error_px: float, points: PointStyle = (None, None, None),
                      area: Rect | None = None, window: Rect | None = None,
                      stop: Callable[[], bool] | None = None) -> DepthRender:
        held = self._scenes.find(scene, request.share if request.mode == "sort-last" else None)
        renderer, share = held.renderer, held.share_version or 0
        renderer.use_tools(tools)
        started = time.perf_counter()
        if isinstance(renderer, PointRenderer):
            if request.mode != "sort-last":
                raise ValueError("point clouds are drawn in the sort-first and sort-last modes, not hybrid")
            if window is not None or (area is not None and area != Rect(0, 0, *size)):
                raise ValueError("a point cloud's sort-last layer is drawn over the whole frame")
            renderer.style(*points[1:])
            layer = renderer.render_layer(camera, size, points[0], subsample, stop)
            return DepthRender(layer, None, None, 0.0, share)
        assert held.planning is not None
        plan = live_plan(held.planning, renderer.pose_of(state), camera, size, request, tile_id, area)
        plan_ms = (time.perf_counter() - started) * 1e3
        if plan is None:
            return DepthRender(None, None, None, plan_ms, share)
        layer, blend = render_plan(renderer, camera, size, plan, state, subsample,
                                   lod_error_px if request.mode == "sort-last" else 0.0, window)
        return DepthRender(layer, plan.exclusive, blend, plan_ms, share)

    async def pick(self, request: Pick) -> PickHit | None:
        """What ``request``'s pixel sees (its scene, or share, in its state, cut by its clip); None:
        background. Raises SceneNotLoadedError for a scene or share not held."""
        return await self._call(self._pick, request)

    def _pick(self, request: Pick) -> PickHit | None:
        renderer = self._scenes.find(request.scene, request.share).renderer
        if isinstance(renderer, PointRenderer):
            raise ValueError("picking is not done on point clouds yet")
        renderer.use_tools(ViewTools(request.clip))
        state = request.state if isinstance(request.state, SceneState) else None
        return renderer.pick(request.camera, request.size, request.x, request.y, state)

    def _close(self) -> None:
        self._scenes.release_all()
        if self._shared is not None:
            self._shared.release()
            self._shared = None
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None

    def close(self) -> None:
        """Kill the scene reader processes (a scene or levels they build are not needed any more),
        stop the loader threads, free GL resources on the GL thread and stop it (waits for a running draw)."""
        self._closing = True
        for reader in (self._reader, self._levels_reader):
            reader.close()
        for loader in (self._loader, self._file_loader, self._levels_loader, self._checker):
            loader.shutdown(wait=True, cancel_futures=True)
        for reader in (self._reader, self._levels_reader):
            reader.close()
        self._executor.submit(self._close)
        self._executor.shutdown(wait=True)
