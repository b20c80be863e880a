"""The render node's network adapter: connect to the coordinator, feed its messages to the node's
protocol core (:class:`node.protocol.NodeProtocol`, where every decision of the conversation is
made) and carry out the actions it hands out with the GL thread (:class:`node.gl.worker.GLWorker`:
each scene loaded once, retained mode, seed 002; several held at once, issue 19), the encoder
thread and the socket; reconnect with exponential back-off. A scene loads in the background (read
in the worker's loader thread, fetched from the coordinator when the node cannot open it): tiles
of the scenes already held go on meanwhile, and its end is fed back to the protocol.

Functional parallelism (seed 002 §4): three stages per tile run concurrently — drawing (the one GL
thread), encoding (an encoder thread, :mod:`node.tile_messages`) and sending (the event loop's
sender task), so tile i+1 is drawn while tile i is compressed and sent. moderngl keeps the GIL
inside GL calls, but the draw's longest wait, ``glFinish``, lets it go
(:func:`node.gl.context.finish`): the event loop, the encoder and a scene read in the background
run meanwhile. A ``load_scene`` starts on receipt, also while a tile is being drawn, and a
``cancel`` of the frame whose tile is being drawn stops a point cloud's draw at its next piece
(:class:`node.gl.point_renderer.DrawStopped`: a still's sample of every point in view is given up
when the camera moves, not drawn to its end).

Depth modes (issue 10): a tile of a ``render`` with a depth request is drawn as a depth layer
(:func:`node.gl.depth_layers.live_plan`: a hybrid tile's owned chunks into tile + strip, or the
node's sort-last share into the rect it projects to) and sent as a depth tile
(:mod:`tessera.wire.depth_tiles`), its byte counts added to the tile's ``tile_sent`` counters. A
``load_scene`` with a share keeps only that share (:mod:`node.scene.shares`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import threading
import time
from collections.abc import Awaitable, Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from node.gl.context import GLUnavailableError
from node.gl.point_renderer import DrawStopped
from node.gl.view_tools import ViewTools
from node.gl.worker import GLWorker
from node.protocol import Draw, Load, Measure, NodeProtocol, PickPixel, Send
from node.scene.data import SceneData
from node.scene.fetch import SceneFetcher
from node.scene.lod import GroupLevels, LodTree, group_levels
from node.scene.pages import resident_mb
from node.scene.points import PointCloud
from node.settings import NodeSettings
from node.tile_messages import cut_pieces, encode_depth_message, encode_tile
from tessera.scheduling.refinement import Subsample
from tessera.wire import messages
from tessera.wire.mesh_update import MeshError
from tessera.wire.pick_messages import Pick, PickResult

log = logging.getLogger("tessera.node")

MAX_MESSAGE_BYTES = 64 << 20
BACKOFF_START_S = 0.2
BACKOFF_MAX_S = 5.0
CLOSE_BAD_TOKEN = 4401


#: Culling-state key of calibration renders, apart from every tile's own slot.
CALIBRATION_SLOT = "calibration"


@dataclass(frozen=True, slots=True)
class PendingTile:
    """A tile whose encoding may still run; the sender awaits it in order. ``stats``: its
    ``tile_sent`` counters (:meth:`RenderedTile.stats`; a depth tile's encoder adds its byte
    counts before ``packed`` is done)."""

    frame: int
    tile: int
    packed: asyncio.Future[bytes]
    stats: dict[str, Any]


#: What the sender sends in order: control messages, and tiles once encoded.
Outbox = asyncio.Queue[messages.Message | PendingTile]


class NodeClient:
    """One render node: ``await NodeClient(settings).run(stop)`` until ``stop`` is set. Its
    :attr:`protocol` decides; this carries out."""

    def __init__(self, settings: NodeSettings, worker: GLWorker | None = None,
                 sleep: Callable[[float], Awaitable[Any]] = asyncio.sleep) -> None:
        self.settings = settings
        self.worker = worker or GLWorker(settings.culling, settings.face_limit, settings.scene_memory_mb << 20,
                                         SceneFetcher(settings.coordinator, settings.token, settings.scene_cache_dir),
                                         shading=settings.shading, cache=settings.cache)
        self.protocol = NodeProtocol(settings.name, settings.token or "", settings.slowdown, settings.host)
        self._sleep = sleep
        self._encoder = ThreadPoolExecutor(1, thread_name_prefix="tessera-encode")
        self.renderer_name = ""
        #: The frame whose tile the GL thread draws and the event that stops it (None: no tile drawn).
        self._drawing: tuple[int, threading.Event] | None = None

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
            bad_token, why = await self._connect_once(self.protocol.connect(self.renderer_name))
            if self.protocol.welcomed:
                delay = BACKOFF_START_S
            (log.error if bad_token else log.warning)("%s; reconnecting in %.1f s", why, delay)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stop.wait(), delay)
            delay = min(delay * 2.0, BACKOFF_MAX_S)

    async def _connect_once(self, hello: messages.NodeHello) -> tuple[bool, str]:
        """One connection, opened with ``hello`` and served until it ends; returns (token rejected,
        why it ended)."""
        url = self.settings.coordinator
        try:
            async with connect(url, max_size=MAX_MESSAGE_BYTES, compression=None, proxy=None) as ws:
                log.info("connected to %s", url)
                await ws.send(hello.to_text())
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

    async def _session(self, ws: ClientConnection) -> None:
        work = asyncio.Event()
        outbox: Outbox = asyncio.Queue()
        self.worker.levels_listener = lambda spec, share, tree, scene, groups: outbox.put_nowait(
            levels_ready(spec, share, tree, scene, groups))
        loads: set[asyncio.Task[None]] = set()

        def start_load(action: Load) -> None:
            """Read the scene in the background (in ``loads``); its end wakes ``work``."""
            load = asyncio.create_task(self._load_scene(action.request, outbox, work))
            loads.add(load)
            load.add_done_callback(loads.discard)

        tasks = [asyncio.create_task(self._receive(ws, work, start_load)),
                 asyncio.create_task(self._send_loop(ws, outbox)),
                 asyncio.create_task(self._job_loop(work, outbox, start_load))]
        try:
            done, _ = await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in (*tasks, *loads):   # a scene being read goes on in the worker, for the next connection
                task.cancel()
            await asyncio.gather(*tasks, *loads, return_exceptions=True)
        for task in done:
            error = None if task.cancelled() else task.exception()
            if error is not None and not isinstance(error, ConnectionClosed):
                log.error("node session failed", exc_info=error)
                await ws.close(1011, "node error")

    async def _receive(self, ws: ClientConnection, work: asyncio.Event, start_load: Callable[[Load], None]) -> None:
        """Each text message goes to the protocol on receipt (a cancel or the welcome takes effect
        there and then, a load it hands out is started by ``start_load``, even while a tile is being
        drawn); ``work`` wakes the job loop for what it queued."""
        async for raw in ws:
            if isinstance(raw, bytes):   # a mesh sent as arrays (issue 33), before the load_scene of it
                try:
                    self.worker.meshes.receive(raw)
                except MeshError as exc:
                    log.warning("ignoring a binary message from the coordinator: %s", exc)
                continue
            self.protocol.receive_text(raw)
            self._stop_if_cancelled()
            while (load := self.protocol.next_load()) is not None:
                start_load(load)
            work.set()

    async def _job_loop(self, work: asyncio.Event, outbox: Outbox, start_load: Callable[[Load], None]) -> None:
        """Carry out the protocol's actions in order, each done before the next is asked for, but
        loads: each goes on in the background (``start_load``) and wakes ``work`` when it ends."""
        while True:
            action = self.protocol.next_action()
            match action:
                case None:
                    work.clear()
                    await work.wait()
                case Send():
                    outbox.put_nowait(action.message)
                case Load():
                    start_load(action)
                case Measure():
                    await self._calibrate(action, outbox)
                case Draw():
                    await self._draw(action, outbox)
                case PickPixel():
                    await self._pick(action.request, outbox)

    async def _load_scene(self, message: messages.LoadScene, outbox: Outbox, work: asyncio.Event) -> None:
        """Load ``message``'s scene, tell the protocol how it ended and queue its answer."""
        loop = asyncio.get_running_loop()
        spec = message.scene

        def progress(fraction: float, text: str) -> None:
            update = messages.SceneProgress(scene=spec, fraction=fraction, message=text, rss_mb=round(resident_mb(), 1))
            loop.call_soon_threadsafe(outbox.put_nowait, update)

        started = time.perf_counter()
        try:
            loaded = await self.worker.load(message, progress)
        except Exception as exc:  # SceneError, or a GL failure while uploading
            outbox.put_nowait(self.protocol.scene_failed(message, exc))
        else:
            scene = loaded.scene
            what = f"{scene.point_count} points in {scene.nodes.count} octree nodes" if isinstance(scene, PointCloud) \
                else f"{scene.triangle_count} triangles, {len(scene.batches)} meshes, {scene.chunks.chunk_count} chunks"
            log.info("scene %s ready: %s, %.0f ms", spec, what, (time.perf_counter() - started) * 1e3)
            ready = self.protocol.scene_loaded(message, scene, loaded.share_version)
            if loaded.levels is not None:   # before 'ready': the first frame drawn on this node may use them
                outbox.put_nowait(levels_ready(spec, loaded.share_version, loaded.levels, scene,
                                               loaded.group_levels))
            outbox.put_nowait(ready.model_copy(update={"scene_mb": round(loaded.nbytes / (1 << 20), 2),
                                                       "held_mb": round(loaded.held_bytes / (1 << 20), 2),
                                                       "rss_mb": round(resident_mb(), 1)}))
        work.set()

    def _stop_if_cancelled(self) -> None:
        """Stop the draw under way when its frame was cancelled."""
        if self._drawing is not None and self.protocol.cancelled(self._drawing[0]):
            self._drawing[1].set()

    @contextlib.contextmanager
    def _stoppable(self, frame: int) -> Iterator[Callable[[], bool]]:
        """While a tile of ``frame`` is drawn: what tells the GL thread to give it up."""
        stop = threading.Event()
        self._drawing = (frame, stop)
        self._stop_if_cancelled()
        try:
            yield stop.is_set
        finally:
            self._drawing = None

    async def _draw(self, action: Draw, outbox: Outbox) -> None:
        """One tile (or a wall tile's pieces, drawn as one): drawn on the GL thread, encoded in the
        encoder thread (each piece on its own), queued to send in order."""
        job, request, state = action.render, action.tile, action.state
        if job.depth is not None:
            await self._draw_depth(action, job.depth, outbox)
            return
        try:
            with self._stoppable(job.frame) as stop:
                rendered = await self.worker.render(job.camera, job.size, request.rect, request.tile, state,
                                                    action.scene, Subsample.of(job.jitter, job.lod_bias),
                                                    ViewTools.of(job), job.lod_error_px or 0.0, job.window,
                                                    (job.point_budget, job.point_size, job.point_spacing_px), stop)
        except DrawStopped:
            outbox.put_nowait(self.protocol.draw_stopped(job.frame, [tile.tile for tile in action.sent]))
            return
        except Exception as exc:  # a bad rect, a scene not held, or a GL failure: report, keep serving
            for tile in action.sent:
                outbox.put_nowait(self.protocol.tile_failed(job.frame, tile.tile, exc))
            return
        render_ms = await self._slow_down(rendered.render_ms)
        loop = asyncio.get_running_loop()
        for tile, (piece, piece_ms) in zip(action.sent, cut_pieces(rendered, render_ms, action.sent), strict=True):
            packed = loop.run_in_executor(self._encoder, encode_tile, job.frame, tile, piece, piece_ms, job.codec,
                                          job.jpeg_quality, state)
            outbox.put_nowait(PendingTile(job.frame, tile.tile, packed, piece.stats()))

    async def _slow_down(self, render_ms: float) -> float:
        """Sleep the emulated slowdown's extra time for a render of ``render_ms``; its time as reported."""
        slowdown = self.settings.slowdown
        if slowdown > 1.0:
            await self._sleep((slowdown - 1.0) * render_ms / 1e3)
            render_ms *= slowdown
        return render_ms

    async def _draw_depth(self, action: Draw, depth: messages.DepthRequest, outbox: Outbox) -> None:
        """One tile of a depth ``render``: drawn as a layer, encoded as a depth tile in the encoder thread."""
        job, request, state = action.render, action.tile, action.state
        try:
            with self._stoppable(job.frame) as stop:
                drawn = await self.worker.render_depth(job.camera, job.size, depth, request.tile, state, action.scene,
                                                       Subsample.of(job.jitter, job.lod_bias), ViewTools.of(job),
                                                       job.lod_error_px or 0.0,
                                                       (job.point_budget, job.point_size, job.point_spacing_px),
                                                       request.rect, job.window, stop)
        except DrawStopped:
            outbox.put_nowait(self.protocol.draw_stopped(job.frame, [request.tile]))
            return
        except Exception as exc:  # a bad tile id, a scene or share not held, or a GL failure: report, keep serving
            outbox.put_nowait(self.protocol.tile_failed(job.frame, request.tile, exc))
            return
        render_ms, readback_ms = drawn.times
        render_ms = await self._slow_down(render_ms)
        stats = drawn.stats()
        packed = asyncio.get_running_loop().run_in_executor(
            self._encoder, encode_depth_message, job.frame, request, drawn.depth_layer(), drawn.core,
            drawn.blend_layer(), (render_ms, readback_ms), job.codec, job.jpeg_quality, state, drawn.share, stats)
        outbox.put_nowait(PendingTile(job.frame, request.tile, packed, stats))

    async def _pick(self, request: Pick, outbox: Outbox) -> None:
        """Answer a ``pick`` (issue 35): the id pass of its pixel on the GL thread, then its result,
        or the reason it could not be told."""
        try:
            hit = await self.worker.pick(request)
        except Exception as exc:  # a scene or share not held, a GL failure: answer with the reason
            outbox.put_nowait(PickResult(id=request.id, hit=False, error=" ".join(str(exc).split())[:300]))
            return
        answer = {"hit": False} if hit is None else hit.to_json()
        outbox.put_nowait(PickResult(id=request.id, **answer))

    async def _calibrate(self, action: Measure, outbox: Outbox) -> None:
        """Seed 003 §1: render the coordinator's central region ``repeats`` times without output and
        report the best time (× slowdown, after sleeping the emulated extra, like a tile)."""
        job = action.request
        try:
            times = [(await self.worker.render(job.camera, job.size, job.rect, CALIBRATION_SLOT, None, action.scene,
                                               lod_error_px=job.lod_error_px or 0.0)).render_ms
                     for _ in range(job.repeats)]
        except Exception as exc:  # a scene not held, a bad rect or a GL failure: report, keep serving
            outbox.put_nowait(self.protocol.calibration_failed(exc))
            return
        best = min(times)
        if self.settings.slowdown > 1.0:
            await self._sleep((self.settings.slowdown - 1.0) * best / 1e3)
        outbox.put_nowait(messages.Calibration(ms=best * self.settings.slowdown))

    async def _send_loop(self, ws: ClientConnection, outbox: Outbox) -> None:
        while True:
            item = await outbox.get()
            if isinstance(item, messages.Message):
                await ws.send(item.to_text())
                continue
            try:
                packed = await item.packed
            except Exception as exc:
                outbox.put_nowait(self.protocol.encoding_failed(item.frame, item.tile, exc))
                continue
            started = time.perf_counter()
            await ws.send(packed)
            send_ms = (time.perf_counter() - started) * 1e3
            sent = messages.TileSent(frame=item.frame, tile=item.tile, send_ms=send_ms, stats=item.stats,
                                     rss_mb=round(resident_mb(), 1))
            await ws.send(sent.to_text())


def levels_ready(spec: str, share: int | None, tree: LodTree, scene: SceneData,
                 groups: GroupLevels | None = None) -> messages.LevelsReady:
    """The ``levels_ready`` of scene ``spec`` (share version ``share``), ``scene``, whose levels are
    ``tree``: with its primitive groups' levels (:func:`node.scene.lod.group_levels`; ``groups``:
    worked out already, in the loader thread)."""
    errors, triangles, boxes = groups or group_levels(tree, scene.groups.chunk_starts, scene.chunks.face_counts,
                                                      scene.chunks.boxes)
    return messages.LevelsReady(scene=spec, share=share, nodes=tree.node_count, triangles=int(tree.triangles.sum()),
                                group_errors=errors.tolist(), group_triangles=triangles.round(1).tolist(),
                                group_boxes=boxes.tolist())


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

