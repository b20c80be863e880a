"""The render node's GL thread (:class:`GLWorker`): the one thread that owns the GL context, where
scenes are loaded, uploaded and drawn — plain tiles, depth tiles (:mod:`node.gl.depth_layers`) and
calibration renders — for :class:`node.client.NodeClient`, which awaits each call."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import moderngl

from node.culling.switch import CullMode
from node.gl.context import create_gl_context, renderer_string
from node.gl.depth_layers import PlanningScene, as_depth_layer, live_plan, render_plan
from node.gl.renderer import BlendedFragments, RenderedTile, TileRenderer
from node.scene.data import SceneData
from node.scene.loading import ProgressCallback, load_scene
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.scene.shares import keep_share
from tessera.compositing.layers import BlendLayer, DepthLayer
from tessera.geometry import Camera, Rect
from tessera.scene.state import SceneState
from tessera.wire.messages import DepthRequest, ShareSpec


@dataclass(frozen=True, slots=True)
class DepthRender:
    """A depth tile as drawn: its ``layer`` (None: nothing of it in view), its ``core`` (sent
    without depth; None: none), its blended fragments drawn apart (sort-last; None: none) and the
    ms spent choosing its chunks."""

    layer: RenderedTile | None
    core: Rect | None
    blend: BlendedFragments | None
    plan_ms: float

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


class GLWorker:
    """The one thread that owns the GL context: scenes are loaded (split into chunks of at most
    ``face_limit`` faces; in sort-last only a share kept), uploaded and drawn (with ``culling``)
    only there.

    The loaded scene survives reconnects; asking for the same scene (and share) again reuses it.
    ``share_version``: the data partition version of the share loaded (None: the whole scene).
    """

    def __init__(self, culling: CullMode = CullMode.AUTO, face_limit: int = DEFAULT_FACE_LIMIT) -> None:
        self._executor = ThreadPoolExecutor(1, thread_name_prefix="tessera-gl")
        self._ctx: moderngl.Context | None = None
        self._renderer: TileRenderer | None = None
        self._planning: PlanningScene | None = None
        self.scene_spec: str | None = None
        self._share: tuple[int, tuple[float, ...]] | None = None
        self.share_version: int | None = None
        self.culling, self.face_limit = culling, face_limit

    async def _call(self, function: Callable[..., Any], *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self._executor, function, *args)

    async def start(self) -> str:
        """Create the context; returns the GL renderer string. Raises GLUnavailableError."""
        return await self._call(self._start)

    def _start(self) -> str:
        self._ctx = create_gl_context()
        return renderer_string(self._ctx)

    async def load(self, spec: str, background: Sequence[float] | None, progress: ProgressCallback,
                   share: ShareSpec | None = None) -> SceneData:
        """Load and upload ``spec`` (only ``share`` of it, if given), or reuse it when already
        loaded; raises SceneError."""
        return await self._call(self._load, spec, background, progress, share)

    def _load(self, spec: str, background: Sequence[float] | None, progress: ProgressCallback,
              share: ShareSpec | None) -> SceneData:
        assert self._ctx is not None
        share_key = None if share is None else (share.index, share.weights)
        if self._renderer is not None and spec == self.scene_spec and share_key == self._share:
            if background is not None:
                self._renderer.background = background
            self.share_version = None if share is None else share.version
            return self._renderer.scene
        self._release_scene()
        scene = load_scene(spec, progress, self.face_limit)
        if share is not None:
            progress(0.8, f"keeping share {share.index + 1} of {len(share.weights)}")
            scene = keep_share(scene, share.weights, share.index)
        progress(0.9, f"uploading {scene.triangle_count} triangles in {scene.chunks.chunk_count} chunks")
        if background is None:
            self._renderer = TileRenderer(self._ctx, scene, culling=self.culling)
        else:
            self._renderer = TileRenderer(self._ctx, scene, background, culling=self.culling)
        self._planning = PlanningScene.of(scene, self._renderer.culler.bvh)
        self.scene_spec, self._share = spec, share_key
        self.share_version = None if share is None else share.version
        return scene

    async def render(self, camera: Camera, size: tuple[int, int], rect: Rect, slot: Hashable,
                     state: SceneState | None = None) -> RenderedTile:
        """Render ``rect`` in scene ``state`` (None: the base pose); ``slot`` (the tile id) keys the
        tile's hybrid culling switch."""
        return await self._call(self._render, camera, size, rect, slot, state)

    def _render(self, camera: Camera, size: tuple[int, int], rect: Rect, slot: Hashable,
                state: SceneState | None) -> RenderedTile:
        if self._renderer is None:
            raise RuntimeError("no scene loaded")
        return self._renderer.render_tile(camera, size, rect, slot, state=state)

    async def render_depth(self, camera: Camera, size: tuple[int, int], request: DepthRequest, tile_id: int,
                           state: SceneState | None) -> DepthRender:
        """Tile ``tile_id`` of a depth ``request`` in scene ``state`` as a depth layer."""
        return await self._call(self._render_depth, camera, size, request, tile_id, state)

    def _render_depth(self, camera: Camera, size: tuple[int, int], request: DepthRequest, tile_id: int,
                      state: SceneState | None) -> DepthRender:
        if self._renderer is None or self._planning is None:
            raise RuntimeError("no scene loaded")
        if request.mode == "sort-last" and request.share != self.share_version:
            raise RuntimeError(f"share of partition {request.share} asked for; this node holds "
                               f"{self.share_version or 'the whole scene'}")
        started = time.perf_counter()
        plan = live_plan(self._planning, self._renderer.pose_of(state), camera, size, request, tile_id)
        plan_ms = (time.perf_counter() - started) * 1e3
        if plan is None:
            return DepthRender(None, None, None, plan_ms)
        layer, blend = render_plan(self._renderer, camera, size, plan, state)
        return DepthRender(layer, plan.exclusive, blend, plan_ms)

    def _release_scene(self) -> None:
        if self._renderer is not None:
            self._renderer.release()
        self._renderer, self._planning, self.scene_spec, self._share, self.share_version = None, None, None, None, None

    def _close(self) -> None:
        self._release_scene()
        if self._ctx is not None:
            self._ctx.release()
            self._ctx = None

    def close(self) -> None:
        """Free GL resources on the GL thread and stop it (waits for a running draw)."""
        self._executor.submit(self._close)
        self._executor.shutdown(wait=True)
