"""The render node's network loop: connect to the coordinator, load the scene once (retained mode,
seed 002), render assigned tiles, stream them back; reconnect with exponential back-off.

Functional parallelism (seed 002 §4): three stages per tile run concurrently — drawing (the one GL
thread), encoding (an encoder thread) and sending (the event loop's sender task), so tile i+1 is
drawn while tile i is compressed and sent. moderngl keeps the GIL inside GL calls, so on CPython the
overlap is the kernel's transfer of queued bytes and the encoder's GIL-free stretches.

Messages follow the catalogue in :mod:`tessera.wire.messages`. Each ``render`` message brings the
node's :class:`tessera.scene.state.StateReplica` to its frame's scene state (issue 11), applied in
message order, also for a frame cancelled since; the tiles are drawn in exactly that state and
their headers say which.

Depth modes (issue 10): a ``render`` with a depth request has each tile drawn as a depth layer
(:func:`node.gl.depth_layers.live_plan`: a hybrid tile's owned chunks into tile + strip, or the
node's sort-last share into the rect it projects to) and sent as a depth tile
(:mod:`tessera.wire.depth_tiles`), its byte counts added to the tile's ``tile_sent`` counters. A
``load_scene`` with a share keeps only that share (:mod:`node.scene.shares`); of several
``load_scene`` messages waiting, only the newest is loaded.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import time
from collections import deque
from collections.abc import Awaitable, Callable, Hashable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import moderngl
from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from node.culling.switch import CullMode
from node.gl.context import GLUnavailableError, create_gl_context, renderer_string
from node.gl.depth_layers import PlanningScene, as_depth_layer, live_plan, render_plan
from node.gl.renderer import BlendedFragments, RenderedTile, TileRenderer
from node.scene.data import SceneData
from node.scene.loading import ProgressCallback, load_scene
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.scene.shares import keep_share
from node.settings import NodeSettings
from tessera.compositing.layers import BlendLayer, DepthLayer
from tessera.geometry import Camera, Rect
from tessera.scene.state import SceneState, SceneStateError, StateReplica
from tessera.wire.codec import Codec, encode
from tessera.wire.depth_tiles import encode_depth_tile
from tessera.wire.messages import (
    TO_NODE,
    Calibrate,
    Calibration,
    Cancel,
    Capabilities,
    DepthRequest,
    InvalidMessage,
    LoadScene,
    Message,
    NodeHello,
    Render,
    RenderError,
    RenderTile,
    SceneError,
    SceneGroups,
    SceneProgress,
    SceneReady,
    ShareSpec,
    TilesDropped,
    TileSent,
    Welcome,
    parse,
)
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError, TileHeader, pack_tile, state_tag

log = logging.getLogger("tessera.node")

MAX_MESSAGE_BYTES = 64 << 20
#: Cancelled frame ids a node remembers (its queue never holds more frames than this).
CANCELLED_MEMORY = 256
BACKOFF_START_S = 0.2
BACKOFF_MAX_S = 5.0
CLOSE_BAD_TOKEN = 4401


#: Culling-state key of calibration renders, apart from every tile's own slot.
CALIBRATION_SLOT = "calibration"
#: The node's work, done in order: coordinator messages, and malformed ones to answer.
Job = LoadScene | Render | Calibrate | InvalidMessage


def encode_tile(frame: int, tile: RenderTile, rendered: RenderedTile, render_ms: float,
                codec: Codec, jpeg_quality: int, state: SceneState | None = None) -> bytes:
    """The binary tile message: header with the phase times and the ``state`` drawn + the encoded pixels."""
    started = time.perf_counter()
    payload = encode(rendered.pixels, codec, jpeg_quality)
    encode_ms = (time.perf_counter() - started) * 1e3
    header = TileHeader(frame, tile.tile, tile.rect, codec, render_ms, rendered.readback_ms, encode_ms,
                        state_tag(None if state is None else state.version))
    return pack_tile(header, payload)


def encode_depth_message(frame: int, tile: RenderTile, layer: DepthLayer | None, core: Rect | None,
                         blend: BlendLayer | None, times: tuple[float, float], codec: Codec, jpeg_quality: int,
                         state: SceneState | None, version: int, stats: dict[str, Any]) -> bytes:
    """The binary depth tile message of ``layer`` (None: nothing in view) with its ``core`` as an
    image in ``codec`` and its ``blend`` layer, drawn and read back in ``times`` (ms); the tile's
    byte counts are added to ``stats`` (its ``tile_sent`` counters)."""
    started = time.perf_counter()
    payload, counts = encode_depth_tile(layer, core, codec, jpeg_quality, version, blend)
    encode_ms = (time.perf_counter() - started) * 1e3
    stats.update(counts.as_stats())
    header = TileHeader(frame, tile.tile, tile.rect, codec, *times, encode_ms,
                        state_tag(None if state is None else state.version), depth=True)
    return pack_tile(header, payload)


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


@dataclass(frozen=True, slots=True)
class PendingTile:
    """A tile whose encoding may still run; the sender awaits it in order. ``stats``: its
    ``tile_sent`` counters (:meth:`RenderedTile.stats`; a depth tile's encoder adds its byte
    counts before ``packed`` is done)."""

    frame: int
    tile: int
    packed: asyncio.Future[bytes]
    stats: dict[str, Any]


class NodeClient:
    """One render node: ``await NodeClient(settings).run(stop)`` until ``stop`` is set."""

    def __init__(self, settings: NodeSettings, worker: GLWorker | None = None,
                 sleep: Callable[[float], Awaitable[Any]] = asyncio.sleep) -> None:
        self.settings = settings
        self.worker = worker or GLWorker(settings.culling, settings.face_limit)
        self._sleep = sleep
        self._encoder = ThreadPoolExecutor(1, thread_name_prefix="tessera-encode")
        self.renderer_name = ""
        self.node_id: int | None = None
        self._welcomed = False
        self._cancelled: deque[int] = deque(maxlen=CANCELLED_MEMORY)
        self._replica = StateReplica()
        self._newest_load: LoadScene | None = None
        self.tiles_dropped = 0

    async def run(self, stop: asyncio.Event) -> None:
        """Start the GL thread, then stay connected (with back-off) until ``stop`` is set."""
        try:
            self.renderer_name = await self.worker.start()
            print(f"Tessera node {self.settings.name}: GL renderer {self.renderer_name}", flush=True)
            connecting = asyncio.create_task(self._connect_forever(stop))
            stopping = asyncio.create_task(stop.wait())
            await asyncio.wait([connecting, stopping], return_when=asyncio.FIRST_COMPLETED)
            for task in (connecting, stopping):
                task.cancel()
            await asyncio.gather(connecting, stopping, return_exceptions=True)
        finally:
            self._encoder.shutdown(wait=True)
            await asyncio.to_thread(self.worker.close)
            log.info("node %s stopped", self.settings.name)

    async def _connect_forever(self, stop: asyncio.Event) -> None:
        delay = BACKOFF_START_S
        while not stop.is_set():
            self._welcomed = False
            bad_token, why = await self._connect_once()
            if self._welcomed:
                delay = BACKOFF_START_S
            (log.error if bad_token else log.warning)("%s; reconnecting in %.1f s", why, delay)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), delay)
            delay = min(delay * 2.0, BACKOFF_MAX_S)

    async def _connect_once(self) -> tuple[bool, str]:
        """One connection, served until it ends; returns (token rejected, why it ended)."""
        url = self.settings.coordinator
        try:
            async with connect(url, max_size=MAX_MESSAGE_BYTES, compression=None, proxy=None) as ws:
                log.info("connected to %s", url)
                await self._session(ws)
        except InvalidStatus as exc:
            return False, f"coordinator {url} refused the WebSocket: HTTP {exc.response.status_code}"
        except (OSError, TimeoutError, InvalidHandshake, ConnectionClosed) as exc:
            return False, f"cannot reach coordinator {url} ({exc or type(exc).__name__})"
        if ws.close_code == CLOSE_BAD_TOKEN:
            return True, (f"coordinator {url} rejected this node's token "
                          f"(close {CLOSE_BAD_TOKEN}: {ws.close_reason or 'bad token'})")
        return False, f"connection to {url} closed (code {ws.close_code}{': ' if ws.close_reason else ''}" \
                      f"{ws.close_reason})"

    def hello(self) -> NodeHello:
        return NodeHello(name=self.settings.name, token=self.settings.token or "", renderer=self.renderer_name,
                         version=PROTOCOL_VERSION,
                         capabilities=Capabilities(slowdown=self.settings.slowdown, calibrate=True, depth=True))

    async def _session(self, ws: ClientConnection) -> None:
        self._replica = StateReplica()
        await ws.send(self.hello().to_text())
        jobs: asyncio.Queue[Job] = asyncio.Queue()
        outbox: asyncio.Queue[Message | PendingTile] = asyncio.Queue()
        tasks = [asyncio.create_task(self._receive(ws, jobs)), asyncio.create_task(self._send_loop(ws, outbox)),
                 asyncio.create_task(self._job_loop(jobs, outbox))]
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        for task in done:
            error = None if task.cancelled() else task.exception()
            if error is not None and not isinstance(error, ConnectionClosed):
                log.error("node session failed", exc_info=error)
                await ws.close(1011, "node error")

    async def _receive(self, ws: ClientConnection, jobs: asyncio.Queue[Job]) -> None:
        """Cancels and the welcome take effect at once; everything else is a job, done in order
        (a message that names a kind but is malformed too: it is answered in its turn)."""
        async for raw in ws:
            if isinstance(raw, bytes):
                log.warning("ignoring a binary message from the coordinator")
                continue
            try:
                message = parse(raw, TO_NODE)
            except InvalidMessage as exc:
                jobs.put_nowait(exc)
                continue
            except ProtocolError as exc:
                log.warning("ignoring coordinator message: %s", exc)
                continue
            match message:
                case Cancel():
                    self._cancelled.extend(message.frames)
                case Welcome():
                    self.node_id = message.node_id
                    self._welcomed = True
                    log.info("registered as node %s", self.node_id)
                case LoadScene():
                    self._newest_load = message
                    jobs.put_nowait(message)
                case Render() | Calibrate():
                    jobs.put_nowait(message)

    async def _job_loop(self, jobs: asyncio.Queue[Job], outbox: asyncio.Queue[Message | PendingTile]) -> None:
        while True:
            job = await jobs.get()
            match job:
                case LoadScene():
                    if job is self._newest_load:   # a newer one waits: this one is superseded
                        await self._load_scene(job, outbox)
                case Calibrate():
                    await self._calibrate(job, outbox)
                case Render():
                    await self._render(job, outbox)
                case InvalidMessage():
                    self._refuse(job, outbox)

    def _refuse(self, error: InvalidMessage, outbox: asyncio.Queue[Message | PendingTile]) -> None:
        """Answer a malformed message as far as it can be read: a ``render``'s tiles fail, a
        ``calibrate`` fails, a ``load_scene`` is a scene error."""
        log.warning("bad coordinator message: %s", error)
        data, reason = error.data, str(error)
        if error.kind == Render.kind:
            frame, tiles = data.get("frame"), data.get("tiles")
            if _is_int(frame) and isinstance(tiles, list):
                tile_ids = [t["tile"] for t in tiles if isinstance(t, dict) and _is_int(t.get("tile"))]
                self._render_errors(outbox, frame, tile_ids, reason)
        elif error.kind == Calibrate.kind:
            outbox.put_nowait(RenderError(frame=0, tile=0, message=f"calibration failed: {reason}"))
        elif error.kind == LoadScene.kind:
            outbox.put_nowait(SceneError(scene=str(data.get("scene")), message=reason))

    async def _load_scene(self, message: LoadScene, outbox: asyncio.Queue[Message | PendingTile]) -> None:
        loop = asyncio.get_running_loop()
        spec = message.scene

        def progress(fraction: float, text: str) -> None:
            loop.call_soon_threadsafe(outbox.put_nowait, SceneProgress(scene=spec, fraction=fraction, message=text))

        started = time.perf_counter()
        try:
            scene = await self.worker.load(spec, message.background, progress, message.share)
        except Exception as exc:  # SceneError, or a GL failure while uploading
            reason = " ".join(str(exc).split()) or type(exc).__name__
            log.warning("scene %s failed: %s", spec, reason)
            outbox.put_nowait(SceneError(scene=spec, message=reason))
            return
        load_ms = (time.perf_counter() - started) * 1e3
        log.info("scene %s ready: %d triangles, %d meshes, %d chunks, %.0f ms", spec, scene.triangle_count,
                 len(scene.batches), scene.chunks.chunk_count, load_ms)
        groups = SceneGroups(boxes=scene.groups.boxes.tolist(), counts=scene.groups.counts.tolist(),
                             objects=scene.groups.owners.tolist())
        outbox.put_nowait(SceneReady(triangles=scene.triangle_count, bounds=scene.bounds.tolist(), groups=groups,
                                     objects=scene.objects.to_json(),
                                     animations=[a.keyframes_json() for a in scene.animations],
                                     share=self.worker.share_version))

    async def _render(self, job: Render, outbox: asyncio.Queue[Message | PendingTile]) -> None:
        loop = asyncio.get_running_loop()
        try:
            state = None if job.state is None else self._replica.receive(job.state)
        except SceneStateError as exc:
            self._render_errors(outbox, job.frame, [t.tile for t in job.tiles], f"scene state: {exc}")
            return
        dropped: list[int] = []
        for request in job.tiles:
            if job.frame in self._cancelled:
                dropped.append(request.tile)
                continue
            if job.depth is not None:
                await self._render_depth_tile(job, job.depth, request, state, outbox)
                continue
            try:
                rendered = await self.worker.render(job.camera, job.size, request.rect, request.tile, state)
            except Exception as exc:  # a bad rect, no scene, or a GL failure: report, keep serving
                self._render_errors(outbox, job.frame, [request.tile], " ".join(str(exc).split()))
                continue
            render_ms = await self._slow_down(rendered.render_ms)
            packed = loop.run_in_executor(self._encoder, encode_tile, job.frame, request, rendered, render_ms,
                                          job.codec, job.jpeg_quality, state)
            outbox.put_nowait(PendingTile(job.frame, request.tile, packed, rendered.stats()))
        if dropped:
            self.tiles_dropped += len(dropped)
            log.debug("frame %d superseded: %d queued tiles dropped", job.frame, len(dropped))
            outbox.put_nowait(TilesDropped(frame=job.frame, tiles=tuple(dropped)))

    async def _slow_down(self, render_ms: float) -> float:
        """Sleep the emulated slowdown's extra time for a render of ``render_ms``; its time as reported."""
        slowdown = self.settings.slowdown
        if slowdown > 1.0:
            await self._sleep((slowdown - 1.0) * render_ms / 1e3)
            render_ms *= slowdown
        return render_ms

    async def _render_depth_tile(self, job: Render, depth: DepthRequest, request: RenderTile,
                                 state: SceneState | None, outbox: asyncio.Queue[Message | PendingTile]) -> None:
        """One tile of a depth ``job``: drawn as a layer, encoded as a depth tile in the encoder thread."""
        try:
            drawn = await self.worker.render_depth(job.camera, job.size, depth, request.tile, state)
        except Exception as exc:  # a bad tile id, no scene, another share, or a GL failure: report, keep serving
            self._render_errors(outbox, job.frame, [request.tile], " ".join(str(exc).split()))
            return
        render_ms, readback_ms = drawn.times
        render_ms = await self._slow_down(render_ms)
        stats = drawn.stats()
        packed = asyncio.get_running_loop().run_in_executor(
            self._encoder, encode_depth_message, job.frame, request, drawn.depth_layer(), drawn.core,
            drawn.blend_layer(), (render_ms, readback_ms), job.codec, job.jpeg_quality, state,
            self.worker.share_version or 0, stats)
        outbox.put_nowait(PendingTile(job.frame, request.tile, packed, stats))

    async def _calibrate(self, job: Calibrate, outbox: asyncio.Queue[Message | PendingTile]) -> None:
        """Seed 003 §1: render the coordinator's central region ``repeats`` times without output and
        report the best time (× slowdown, after sleeping the emulated extra, like a tile)."""
        try:
            times = [(await self.worker.render(job.camera, job.size, job.rect, CALIBRATION_SLOT)).render_ms
                     for _ in range(job.repeats)]
        except Exception as exc:  # no scene, a bad rect or a GL failure: report, keep serving
            log.warning("calibration failed: %s", exc)
            outbox.put_nowait(RenderError(frame=0, tile=0,
                                          message=f"calibration failed: {' '.join(str(exc).split())}"))
            return
        best = min(times)
        if self.settings.slowdown > 1.0:
            await self._sleep((self.settings.slowdown - 1.0) * best / 1e3)
        outbox.put_nowait(Calibration(ms=best * self.settings.slowdown))

    @staticmethod
    def _render_errors(outbox: asyncio.Queue[Message | PendingTile], frame: int, tiles: list[int],
                       reason: str) -> None:
        for tile in tiles:
            outbox.put_nowait(RenderError(frame=frame, tile=tile, message=reason))

    async def _send_loop(self, ws: ClientConnection, outbox: asyncio.Queue[Message | PendingTile]) -> None:
        while True:
            item = await outbox.get()
            if isinstance(item, Message):
                await ws.send(item.to_text())
                continue
            try:
                packed = await item.packed
            except Exception as exc:
                self._render_errors(outbox, item.frame, [item.tile], f"encoding failed: {exc}")
                continue
            started = time.perf_counter()
            await ws.send(packed)
            send_ms = (time.perf_counter() - started) * 1e3
            await ws.send(TileSent(frame=item.frame, tile=item.tile, send_ms=send_ms, stats=item.stats).to_text())


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def run_node(settings: NodeSettings) -> int:
    """Run the node until SIGINT/SIGTERM; returns the exit code."""

    async def main() -> int:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(signum, stop.set)
        try:
            await NodeClient(settings).run(stop)
        except GLUnavailableError as exc:
            log.error("%s", exc)
            return 1
        return 0

    return asyncio.run(main())

