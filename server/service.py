"""The coordinator's asyncio adapter around :class:`tessera.scheduling.scheduler.FrameScheduler`: it turns
socket messages and the clock into scheduler events and carries out the scheduler's actions
(send render / cancel messages, publish frames to the store and the viewers, close nodes).

The decomposition mode (:mod:`tessera.decomposition`) lives in the scheduler: it reads each tile
(a depth tile is decoded and checked when it arrives) and assembles each complete frame for the
viewers (a depth frame merged on the coordinator: at 1080p with 4 nodes the merge costs 5–15 ms of
one core, below a node's render time, docs/depth_compositing.md); this module carries bytes.

What happens when — render on demand, late camera binding, superseded frames, publish order —
is decided in the scheduler; this module adds what needs I/O: the nodes' connections and scene
state, calibration (seed 003 §1), the viewers, the frame store, the CPU accounting and the
Prometheus histograms (:mod:`server.metrics`: each publish, each tile's node phases).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from typing import Any

import numpy as np

from server.calibration import CalibrationQueue, calibrate_message
from server.frame_store import FrameStore, PublishedFrame
from server.metrics import CoordinatorMetrics, ObservedFrameStats
from server.nodes import NodeLink
from server.settings import Settings
from server.viewers import ViewerHub
from tessera.balancers import create_balancer
from tessera.balancers.base import Balancer
from tessera.balancers.hetero import calibration_weights
from tessera.geometry import DEFAULT_BACKGROUND, Camera, default_camera
from tessera.scene.animation import Animation, AnimationError
from tessera.scene.graph import ObjectGraph
from tessera.scene.state import ObjectPatch, SceneStateError
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling import actions
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.scheduler import FrameScheduler
from tessera.wire import messages
from tessera.wire.messages import (
    Calibration,
    Cancel,
    Message,
    NodeHello,
    RenderError,
    SceneError,
    SceneProgress,
    SceneReady,
    ShareSpec,
    TilesDropped,
    TileSent,
    ViewerScene,
    Welcome,
)
from tessera.wire.protocol import ProtocolError, unpack_tile

log = logging.getLogger("tessera.server")

#: Longest wait of the timer task between two looks at the scheduler and calibration (s).
TIMER_MAX_WAIT_S = 1.0


def timeline_of(message: SceneReady, now: float) -> SceneTimeline:
    """The scene's objects and animations as a node reported them; ProtocolError when they do not
    make a scene."""
    assert message.objects is not None
    try:
        graph = ObjectGraph.from_json([item.model_dump() for item in message.objects])
        animations = [Animation.from_keyframes_json(item.model_dump()) for item in message.animations]
        return SceneTimeline(graph, animations, now)
    except (SceneStateError, AnimationError) as exc:
        raise ProtocolError(f"scene_ready: {exc}") from None


class RenderService:
    def __init__(self, settings: Settings, metrics: CoordinatorMetrics | None = None) -> None:
        self.settings = settings
        self.size = settings.size
        self.metrics = metrics or CoordinatorMetrics()
        self.scheduler = FrameScheduler(settings.scheduler_config(), create_balancer(settings.balancer))
        self.scheduler.default.stats = ObservedFrameStats(self.metrics)
        self.nodes: dict[int, NodeLink] = {}
        self.bounds: np.ndarray | None = None
        self.store = FrameStore()
        self.viewers = ViewerHub()
        self._next_node_id = 1
        self._wake = asyncio.Event()
        self._tasks: list[asyncio.Task] = []
        self.cpu_ms = {"receive": 0.0, "publish": 0.0, "merge": 0.0}
        self.calibration = CalibrationQueue()

    @property
    def camera(self) -> Camera | None:
        return self.scheduler.default.camera

    @property
    def balancer(self) -> Balancer:
        return self.scheduler.default.mode.tiles.balancer

    @property
    def stats(self):
        return self.scheduler.default.stats

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        self._tasks = [asyncio.create_task(self._timer(), name="scheduler-timer")]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    async def _timer(self) -> None:
        """Tick the scheduler at its next deadline (frame-rate cap, still frame, tile timeouts) and
        look at calibration timeouts every ``TIMER_MAX_WAIT_S``; events only make it look at the
        deadline again, so it costs nothing per tile."""
        calibration_at = time.monotonic()
        while True:
            now = time.monotonic()
            deadline = self.scheduler.next_deadline(now)
            wake_at = min(calibration_at + TIMER_MAX_WAIT_S, deadline if deadline is not None else math.inf)
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), timeout=max(wake_at - now, 0.0))
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                self.scheduler.tick(now)
                self._apply()
            if now >= calibration_at + TIMER_MAX_WAIT_S:
                calibration_at = now
                self._start_calibration()

    def _apply(self) -> None:
        """Carry out the scheduler's actions, then let the timer look at the new deadline."""
        for action in self.scheduler.drain():
            if isinstance(action, actions.RenderTiles):
                self.nodes[action.node_id].send(action.message)
            elif isinstance(action, actions.CancelFrames):
                self.nodes[action.node_id].send(Cancel(frames=action.frames))
            elif isinstance(action, actions.LoadScene):
                self.nodes[action.node_id].send(self._load_scene(action.share))
            elif isinstance(action, actions.BalancerFailed):
                log.error("balancer failed, the static split was used: %s", action.reason)
            elif isinstance(action, actions.PublishFrame):
                self._publish(action.job)
            elif isinstance(action, actions.CloseNode):
                link = self.nodes.get(action.node_id)
                if link is not None:
                    log.warning("node %d (%s): %s; disconnecting it", link.node_id, link.name, action.reason)
                    link.close(action.code, action.reason)
                    self._forget_node(link)
        self._wake.set()

    # ----------------------------------------------------------------- nodes
    def refusal(self, hello: NodeHello) -> str | None:
        """Why a node that sent ``hello`` cannot serve this coordinator (None: it can)."""
        if self.scheduler.default.mode.needs_depth and not hello.capabilities.depth:
            return (f"this coordinator runs --mode {self.settings.mode}, which needs nodes that render depth tiles "
                    "(capabilities.depth); update the node")
        return None

    def add_node(self, hello: NodeHello, close) -> NodeLink:
        name, renderer = hello.name[:64] or "node", hello.renderer[:200]
        link = NodeLink(self._next_node_id, name, renderer, close, slowdown=hello.capabilities.slowdown,
                        can_calibrate=hello.capabilities.calibrate)
        self._next_node_id += 1
        self.nodes[link.node_id] = link
        link.send(Welcome(node_id=link.node_id))
        self.scheduler.add_node(link.node_id, time.monotonic())
        self._apply()   # the scene to load (sort-last: every node's share of the new partition)
        log.info("node %d (%s) joined: %s", link.node_id, name, renderer)
        return link

    def _load_scene(self, share: ShareSpec | None = None) -> messages.LoadScene:
        return messages.LoadScene(scene=self.settings.scene,
                                  background=self.settings.background or DEFAULT_BACKGROUND, share=share)

    def remove_node(self, link: NodeLink) -> None:
        """The node's connection ended: what it owed goes to the others."""
        if self.nodes.get(link.node_id) is not link:
            return
        log.info("node %d (%s) left; %d tiles owed are re-dispatched", link.node_id, link.name,
                 len(self.scheduler.nodes[link.node_id].outstanding))
        self._forget_node(link)
        self.scheduler.remove_node(link.node_id, time.monotonic())
        self._apply()

    def _forget_node(self, link: NodeLink) -> None:
        self.nodes.pop(link.node_id, None)
        self.calibration.forget(link.node_id)
        self._start_calibration()

    def on_node_message(self, link: NodeLink, message: Message) -> None:
        """A control message of :data:`tessera.wire.messages.FROM_NODE` from ``link``."""
        match message:
            case SceneProgress():
                link.progress, link.scene_message = message.fraction, message.message[:200]
            case SceneReady():
                self._on_scene_ready(link, message)
            case SceneError():
                link.state, link.scene_message = "error", message.message[:500]
                log.error("node %d (%s) could not load the scene: %s", link.node_id, link.name, link.scene_message)
            case TileSent():
                if link.last_tile != (message.frame, message.tile):
                    raise ProtocolError(f"tile_sent for tile {message.tile} of frame {message.frame}, which is not "
                                        "the tile this node just sent")
                link.last_tile = None
                self.scheduler.tile_sent(link.node_id, message.frame, message.tile, message.send_ms, message.stats)
                self.metrics.tile_sent(message.send_ms)
            case TilesDropped():
                self.scheduler.tiles_skipped(link.node_id, message.frame, message.tiles)
                link.tiles_dropped += len(message.tiles)
            case Calibration():
                self._on_calibration(link, message.ms)
            case RenderError():
                self._on_render_error(link, message.frame, message.tile, message.message[:300])

    def _on_render_error(self, link: NodeLink, frame_id: int, tile_id: int, reason: str) -> None:
        """A tile the node could not render goes to another node (the scheduler decides when a node
        fails too often); frame 0 is a failed calibration: the node keeps its speed."""
        log.warning("node %d (%s) could not render tile %d of frame %d: %s", link.node_id, link.name, tile_id,
                    frame_id, reason)
        if frame_id == 0:
            if not self.calibration.finished(link.node_id):
                raise ProtocolError("calibration failure without a calibrate request")
            self._start_calibration()
            return
        self.scheduler.tile_failed(link.node_id, frame_id, tile_id, time.monotonic())
        self._apply()

    def _on_scene_ready(self, link: NodeLink, message: SceneReady) -> None:
        bounds = np.asarray(message.bounds, dtype=np.float64)
        link.bounds, link.triangles, link.share = bounds, message.triangles, message.share
        link.state, link.progress, link.scene_message = "ready", 1.0, "ready"
        now = time.monotonic()
        if self.bounds is None:
            if message.objects is not None:
                self.scheduler.set_scene(timeline_of(message, now), now)
            self.bounds = bounds
            if message.groups is not None:
                self.scheduler.set_groups(np.asarray(message.groups.boxes, dtype=np.float64),
                                          np.asarray(message.groups.counts, dtype=np.float64), bounds,
                                          message.groups.objects)
            if self.scheduler.default.camera is None:
                self.scheduler.set_camera(default_camera(bounds, aspect=self.size[0] / self.size[1]), now)
            self.viewers.broadcast(ViewerScene(bounds=message.bounds, camera=self.scheduler.default.camera))
        log.info("node %d (%s) ready: %d triangles%s", link.node_id, link.name, link.triangles,
                 "" if message.share is None else f", its share of partition {message.share}")
        self.scheduler.node_ready(link.node_id, now, message.share)
        self._apply()
        if link.can_calibrate:
            self.calibration.request(link.node_id)
            self._start_calibration()

    # ----------------------------------------------------------------- calibration (seed 003 §1)
    def calibrate_all(self) -> list[int]:
        """Queue every ready node that can calibrate; returns their ids."""
        ids = [n.node_id for n in sorted(self.nodes.values(), key=lambda n: n.node_id) if n.ready and n.can_calibrate]
        for node_id in ids:
            self.calibration.request(node_id)
        self._start_calibration()
        return ids

    def _start_calibration(self) -> None:
        if self.scheduler.default.camera is None:
            return
        node_id = self.calibration.next_to_start(time.monotonic())
        if node_id is not None and node_id in self.nodes:
            self.nodes[node_id].send(calibrate_message(self.scheduler.default.camera, self.size))

    def _on_calibration(self, link: NodeLink, ms: float) -> None:
        if not self.calibration.finished(link.node_id):
            raise ProtocolError("calibration result without a calibrate request")
        link.calibration_ms = ms
        speeds = calibration_weights({n.node_id: n.calibration_ms for n in self.nodes.values()
                                      if n.calibration_ms is not None})
        for node_id, speed in speeds.items():
            self.scheduler.set_speed(node_id, speed)
        log.info("node %d (%s) calibrated: %.2f ms; speeds %s", link.node_id, link.name, ms,
                 {k: round(v, 3) for k, v in speeds.items()})
        self._start_calibration()

    # ----------------------------------------------------------------- camera, scene, balancer
    def set_camera(self, camera: Camera, viewer_id: int | None = None, seq: int | None = None) -> int:
        """Make ``camera`` the newest (``seq``: viewer ``viewer_id``'s input number); returns the
        id of the first frame that can show it."""
        frame = self.scheduler.set_camera(camera, time.monotonic(), viewer_id, seq)
        self._apply()
        return frame

    def set_balancer(self, name: str, params: dict[str, Any]) -> Balancer:
        balancer = create_balancer(name, params)
        self.scheduler.set_balancer(balancer, time.monotonic())
        log.info("balancer set to %s %s", name, balancer.params)
        self._apply()
        return balancer

    def set_objects(self, patches: dict[str, ObjectPatch]) -> int:
        """Pose objects; returns the first frame id that shows it. UnknownObjectError, and nothing
        changes, for a name that is not an object."""
        frame = self.scheduler.set_objects(patches, time.monotonic())
        self._apply()
        return frame

    def set_animation(self, playing: bool | None = None, time_s: float | None = None,
                      speed: float | None = None) -> int:
        """Play, pause, jump to ``time_s``, change speed; returns the first frame id that shows it.
        SceneStateError, and nothing changes, for a bad value."""
        frame = self.scheduler.set_animation(time.monotonic(), playing, time_s, speed)
        self._apply()
        return frame

    def request_frame(self) -> None:
        """Someone waits for a newer frame: render one if nothing is on its way (render on demand)."""
        if self.scheduler.default.settled:
            self.scheduler.invalidate(time.monotonic())
            self._apply()

    def viewer_left(self, viewer_id: int) -> None:
        self.scheduler.default.forget_source(viewer_id)

    # ----------------------------------------------------------------- tiles and frames
    def on_tile_message(self, link: NodeLink, message: bytes) -> None:
        """A binary tile from ``link``: parse, check, hand to the scheduler; CPU time is accounted
        as receive / publish."""
        started = time.thread_time()
        published_before = self.cpu_ms["publish"]
        try:
            header, payload = unpack_tile(message)
            self.scheduler.receive_tile(link.node_id, header, bytes(payload), time.monotonic())
            link.last_tile = (header.frame_id, header.tile_id)
            self.metrics.tile_arrived(header)
            self._apply()
        finally:
            spent = (time.thread_time() - started) * 1000.0
            self.cpu_ms["receive"] += spent - (self.cpu_ms["publish"] - published_before)

    def _frame_tiles(self, job: FrameJob) -> list:
        """What viewers get of ``job`` (the mode's assembly; a merge's CPU time is accounted)."""
        if not self.scheduler.default.mode.merges:
            return self.scheduler.viewer_tiles(job)
        started = time.thread_time()
        tiles = self.scheduler.viewer_tiles(job)
        self.cpu_ms["merge"] += (time.thread_time() - started) * 1000.0
        return tiles

    def _publish(self, job: FrameJob) -> None:
        started = time.thread_time()
        state = job.state
        frame = PublishedFrame(job.frame_id, job.camera, job.size, self._frame_tiles(job), time.monotonic(),
                               still=job.still, inputs=job.inputs,
                               state_version=None if state is None else state.version,
                               scene_time=None if state is None else state.time,
                               tile_states=tuple(t.header.state if t.header else 0 for t in job.tiles))
        self.store.add(frame)
        if self.viewers.slots:
            self.viewers.publish_frame(frame)
        self.cpu_ms["publish"] += (time.thread_time() - started) * 1000.0

    # ----------------------------------------------------------------- reporting
    def scene_state(self) -> dict[str, Any] | None:
        """The newest state version a frame was bound to, the scene time now (s), whether the
        animation plays; None until a node reported the scene's objects."""
        scene = self.scheduler.default.scene
        if scene is None:
            return None
        return {"version": scene.log.current.version, "time": scene.time_at(time.monotonic()),
                "playing": scene.playing, "speed": scene.speed, "animated": bool(scene.animations)}

    def next_frame_id(self) -> int:
        """The id the next frame to start will have."""
        return self.scheduler.next_frame_id

    def scene_timeline(self) -> SceneTimeline | None:
        """The scene's objects, animations and poses (None until a node reported them)."""
        return self.scheduler.default.scene

    def describe(self) -> dict[str, Any]:
        scheduler, stats = self.scheduler, self.scheduler.default.stats
        latest = self.store.latest
        return {
            "frame": max(self.store.last_id, 0),
            "fps": round(stats.fps(time.monotonic()), 2),
            "size": list(self.size),
            "balancer": scheduler.default.mode.tiles.balancer.name,
            **scheduler.default.mode.describe(),
            "balancer_params": scheduler.default.mode.tiles.balancer.params,
            "imbalance": round(stats.imbalance, 4),
            "imbalance_avg": round(stats.imbalance_avg, 4),
            "latency_ms": round(stats.latency_ms, 2),
            "frames_in_flight": len(scheduler.in_flight),
            "frames_cancelled": scheduler.frames_cancelled,
            "still": bool(latest and latest.still),
            "settled": scheduler.default.settled,
            "scene": self.settings.scene,
            "scene_state": self.scene_state(),
            "codec": self.settings.codec.name.lower(),
            "interactive_quality": self.settings.interactive_quality,
            "still_codec": self.settings.still_codec.name.lower() if self.settings.still_codec else "none",
            "viewers": len(self.viewers.slots),
            "viewer_stats": self.viewers.describe(),
            "coordinator_cpu": {
                "frames": stats.frames_published,
                "receive_ms": round(self.cpu_ms["receive"], 3),
                "publish_ms": round(self.cpu_ms["publish"], 3),
                "merge_ms": round(self.cpu_ms["merge"], 3),
                "process_ms": round(time.process_time() * 1000.0, 3),
                "viewer_bytes": self.viewers.bytes_published,
            },
            "nodes": [link.describe(scheduler.nodes[link.node_id])
                      for link in sorted(self.nodes.values(), key=lambda n: n.node_id)],
        }
