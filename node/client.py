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
(:func:`node.gl.depth_layers.live_plan` on the GL thread, :class:`node.gl.worker.GLWorker`: a
hybrid tile's owned chunks into tile + strip, or the node's sort-last share into the rect it
projects to) and sent as a depth tile
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
from collections.abc import Awaitable, Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

from websockets.asyncio.client import ClientConnection, connect
from websockets.exceptions import ConnectionClosed, InvalidHandshake, InvalidStatus

from node.gl.context import GLUnavailableError
from node.gl.worker import GLWorker
from node.settings import NodeSettings
from node.tile_messages import encode_depth_message, encode_tile
from tessera.scene.state import SceneState, SceneStateError, StateReplica
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
    TilesDropped,
    TileSent,
    Welcome,
    parse,
)
from tessera.wire.protocol import PROTOCOL_VERSION, ProtocolError

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

