"""The coordinator's frame loop (seed 004's APP stage): newest camera → partition → dispatch →
gather every tile → publish → feed the measured phases back to the balancer.

Invariants: a frame is published only when all its tiles arrived, all rendered with its one
camera; an older frame is never published after a newer one; at most ``max_in_flight`` frames
render at once (seed 000 §4.1: more frames queued only add latency). A node that leaves owes
nothing: its unfinished tiles go to the remaining nodes.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

import numpy as np

from server.calibration import CalibrationQueue, calibrate_message
from server.frame_jobs import FrameJob
from server.frame_store import FrameStore, PublishedFrame
from server.nodes import NodeLink
from server.settings import Settings
from server.stats import FrameStats
from server.viewers import ViewerHub
from tessera.balancers import create_balancer
from tessera.balancers.base import BalanceInput, Balancer, Partition, TileTiming
from tessera.balancers.hetero import calibration_weights
from tessera.balancers.static import StaticBalancer
from tessera.geometry import DEFAULT_BACKGROUND, Camera, default_camera
from tessera.projection import project_groups
from tessera.protocol import ProtocolError, TileHeader, require, unpack_tile

log = logging.getLogger("tessera.server")


class RenderService:
    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.size = settings.size
        self.nodes: dict[int, NodeLink] = {}
        self.camera: Camera | None = None
        self.bounds: np.ndarray | None = None
        self.balancer: Balancer = create_balancer(settings.balancer)
        self.store = FrameStore()
        self.viewers = ViewerHub()
        self.stats = FrameStats()
        self.in_flight: dict[int, FrameJob] = {}
        self.next_frame_id = 1
        self._next_node_id = 1
        self._wake = asyncio.Event()
        self._last_partition: Partition | None = None
        self._last_partition_at: float | None = None
        self._last_timings: tuple[TileTiming, ...] = ()
        self._next_start_at = 0.0
        self._tasks: list[asyncio.Task] = []
        self._awaiting_send: dict[int, FrameJob] = {}
        self.cpu_ms = {"receive": 0.0, "publish": 0.0}
        self.calibration = CalibrationQueue()

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        self._tasks = [asyncio.create_task(self._frame_loop(), name="frame-loop"),
                       asyncio.create_task(self._watchdog(), name="tile-watchdog")]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    def wake(self) -> None:
        self._wake.set()

    # ----------------------------------------------------------------- nodes
    def add_node(self, hello: dict[str, Any], close) -> NodeLink:
        name = str(require(hello, "name", str))[:64] or "node"
        renderer = str(hello.get("renderer", "unknown"))[:200]
        capabilities = hello.get("capabilities") if isinstance(hello.get("capabilities"), dict) else {}
        slowdown = capabilities.get("slowdown", 1.0)
        link = NodeLink(self._next_node_id, name, renderer, close,
                        slowdown=float(slowdown) if isinstance(slowdown, (int, float)) else 1.0,
                        can_calibrate=capabilities.get("calibrate") is True, idle_since=time.monotonic())
        self._next_node_id += 1
        self.nodes[link.node_id] = link
        link.send({"type": "welcome", "node_id": link.node_id})
        link.send({"type": "load_scene", "scene": self.settings.scene,
                   "background": list(self.settings.background or DEFAULT_BACKGROUND)})
        log.info("node %d (%s) joined: %s", link.node_id, name, renderer)
        return link

    def remove_node(self, link: NodeLink) -> None:
        if self.nodes.pop(link.node_id, None) is None:
            return
        log.info("node %d (%s) left; %d tiles owed are re-dispatched", link.node_id, link.name, len(link.outstanding))
        link.outstanding.clear()
        self.calibration.forget(link.node_id)
        self._start_calibration()
        ready = self.ready_nodes()
        for job in list(self.in_flight.values()):
            owed = job.owed_by(link.node_id)
            if not owed:
                continue
            if not ready:
                del self.in_flight[job.frame_id]
                log.warning("frame %d dropped: no ready node left", job.frame_id)
                continue
            if job.pull:
                for tile_id in reversed(owed):
                    job.tiles[tile_id].node_id = None
                    job.pull_queue.appendleft(tile_id)
            else:
                for tile_id in owed:
                    target = min(ready, key=lambda n: (len(n.outstanding), n.node_id))
                    self._push(job, target, [tile_id])
        self._pump_pull()
        self.wake()

    def on_node_message(self, link: NodeLink, message: dict[str, Any]) -> None:
        kind = message["type"]
        if kind == "scene_progress":
            fraction = message.get("fraction")
            link.progress = float(fraction) if isinstance(fraction, (int, float)) else 0.0
            link.scene_message = str(message.get("message", ""))[:200]
        elif kind == "scene_ready":
            self._on_scene_ready(link, message)
        elif kind == "scene_error":
            link.state = "error"
            link.scene_message = str(message.get("message", "scene failed to load"))[:500]
            log.error("node %d (%s) could not load the scene: %s", link.node_id, link.name, link.scene_message)
        elif kind == "tile_sent":
            frame_id, tile_id = require(message, "frame", int), require(message, "tile", int)
            send_ms = require(message, "send_ms", (int, float))
            job = self.in_flight.get(frame_id) or self._awaiting_send.get(frame_id)
            stats = message.get("stats")
            counters = ({str(k)[:40]: v if not isinstance(v, str) else v[:40] for k, v in stats.items()
                         if isinstance(v, (int, float, str)) and not isinstance(v, bool)}
                        if isinstance(stats, dict) else {})
            if job is not None:
                job.record_send(link.node_id, tile_id, max(float(send_ms), 0.0), counters)
                self._maybe_take_timings(job)
        elif kind == "calibration":
            self._on_calibration(link, require(message, "ms", (int, float)))
        elif kind == "render_error":
            raise ProtocolError(f"node failed to render: {str(message.get('message'))[:300]}")

    def _on_scene_ready(self, link: NodeLink, message: dict[str, Any]) -> None:
        bounds = np.asarray(require(message, "bounds", list), dtype=np.float64)
        if bounds.shape != (2, 3) or not np.isfinite(bounds).all():
            raise ProtocolError("scene_ready.bounds must be [[x,y,z],[x,y,z]] finite numbers")
        link.bounds = bounds
        link.triangles = int(message.get("triangles", 0))
        link.groups = message.get("groups") if isinstance(message.get("groups"), dict) else None
        link.state, link.progress, link.scene_message = "ready", 1.0, "ready"
        link.idle_since = time.monotonic()
        if self.bounds is None:
            self.bounds = bounds
            if self.camera is None:
                self.camera = default_camera(bounds, aspect=self.size[0] / self.size[1])
            self.viewers.broadcast({"type": "scene", "bounds": bounds.tolist(), "camera": self.camera.to_json()})
        log.info("node %d (%s) ready: %d triangles", link.node_id, link.name, link.triangles)
        if link.can_calibrate:
            self.calibration.request(link.node_id)
            self._start_calibration()
        self.wake()

    # ----------------------------------------------------------------- calibration (seed 003 §1)
    def calibrate_all(self) -> list[int]:
        """Queue every ready node that can calibrate; returns their ids."""
        ids = [n.node_id for n in self.ready_nodes() if n.can_calibrate]
        for node_id in ids:
            self.calibration.request(node_id)
        self._start_calibration()
        return ids

    def _start_calibration(self) -> None:
        if self.camera is None:
            return
        node_id = self.calibration.next_to_start(time.monotonic())
        if node_id is not None and node_id in self.nodes:
            self.nodes[node_id].send(calibrate_message(self.camera, self.size))

    def _on_calibration(self, link: NodeLink, ms: float) -> None:
        if not self.calibration.finished(link.node_id):
            raise ProtocolError("calibration result without a calibrate request")
        if not ms > 0.0:
            raise ProtocolError(f"calibration time must be > 0 ms, got {ms}")
        link.calibration_ms = float(ms)
        speeds = calibration_weights({n.node_id: n.calibration_ms for n in self.nodes.values()
                                    if n.calibration_ms is not None})
        for node_id, speed in speeds.items():
            self.nodes[node_id].speed = speed
        log.info("node %d (%s) calibrated: %.2f ms; speeds %s", link.node_id, link.name, ms,
                 {k: round(v, 3) for k, v in speeds.items()})
        self._start_calibration()

    def ready_nodes(self) -> list[NodeLink]:
        return [n for n in sorted(self.nodes.values(), key=lambda n: n.node_id) if n.ready]

    # ----------------------------------------------------------------- camera and balancer
    def set_camera(self, camera: Camera) -> int:
        """Make ``camera`` the newest; returns the id of the first frame that will use it."""
        self.camera = camera
        self.wake()
        return self.next_frame_id

    def set_balancer(self, name: str, params: dict[str, Any]) -> Balancer:
        balancer = create_balancer(name, params)
        self.balancer = balancer
        self._last_partition = None
        self.stats.reset_imbalance()
        log.info("balancer set to %s %s", name, balancer.params)
        self.wake()
        return balancer

    # ----------------------------------------------------------------- frame loop
    async def _frame_loop(self) -> None:
        while True:
            delay = self._start_frames()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), timeout=delay)
            self._wake.clear()

    def _start_frames(self) -> float | None:
        """Start as many frames as allowed; returns seconds until the frame-rate cap allows the next."""
        while True:
            ready = self.ready_nodes()
            if not ready or self.camera is None or len(self.in_flight) >= self.settings.max_in_flight:
                return None
            now = time.monotonic()
            if now < self._next_start_at:
                return self._next_start_at - now
            self._next_start_at = now + 1.0 / self.settings.max_fps
            self._start_frame(ready, now)

    def _start_frame(self, ready: list[NodeLink], now: float) -> None:
        partition = self._partition(ready, now)
        job = FrameJob.create(self.next_frame_id, self.camera, self.size, self.settings.codec,
                              self.settings.jpeg_quality, partition, now)
        self.next_frame_id += 1
        self.in_flight[job.frame_id] = job
        if job.pull:
            self._pump_pull()
        else:
            by_node: dict[int, list[int]] = {}
            for tile in job.tiles:
                by_node.setdefault(tile.node_id, []).append(tile.tile_id)
            for node_id, tile_ids in by_node.items():
                self._push(job, self.nodes[node_id], tile_ids)

    def _partition(self, ready: list[NodeLink], now: float) -> Partition:
        elapsed_ms = 0.0 if self._last_partition_at is None else (now - self._last_partition_at) * 1000.0
        inputs = BalanceInput(
            size=self.size, node_ids=tuple(n.node_id for n in ready), previous=self._last_partition,
            timings=self._last_timings, weights={n.node_id: n.speed for n in ready}, elapsed_ms=elapsed_ms,
            groups=self._projected_groups(ready) if self.balancer.uses_groups else None)
        try:
            partition = self.balancer.partition(inputs)
            self._check_partition(partition, inputs)
        except Exception:
            log.exception("balancer %s failed; using the static split for this frame", self.balancer.name)
            partition = StaticBalancer().partition(inputs)
        self._last_partition, self._last_partition_at = partition, now
        return partition

    def _projected_groups(self, ready: list[NodeLink]):
        """The scene's primitive groups (reported by a node at load) projected for this frame's camera."""
        groups = next((n.groups for n in ready if n.groups), None)
        if groups is None or self.camera is None or self.bounds is None:
            return None
        try:
            boxes = np.asarray(groups["boxes"], dtype=np.float64).reshape(-1, 6)
            counts = np.asarray(groups["counts"], dtype=np.float64).reshape(-1)
        except (KeyError, TypeError, ValueError):
            return None
        if len(boxes) != len(counts) or not np.isfinite(boxes).all():
            return None
        return project_groups(boxes, counts, self.camera, self.size, self.bounds)

    def _check_partition(self, partition: Partition, inputs: BalanceInput) -> None:
        width, height = self.size
        if sum(t.rect.area for t in partition.tiles) != width * height:
            raise ValueError("partition does not cover the screen")
        for tile in partition.tiles:
            r = tile.rect
            if r.w <= 0 or r.h <= 0 or r.x < 0 or r.y < 0 or r.x1 > width or r.y1 > height:
                raise ValueError(f"tile {r} outside the screen")
            if not partition.pull and tile.node_id not in inputs.node_ids:
                raise ValueError(f"tile assigned to unknown node {tile.node_id}")

    def _push(self, job: FrameJob, link: NodeLink, tile_ids: list[int]) -> None:
        now = time.monotonic()
        for tile_id in tile_ids:
            job.tiles[tile_id].node_id = link.node_id
            link.outstanding[(job.frame_id, tile_id)] = now
        link.send(job.render_message(tile_ids))

    def _pump_pull(self) -> None:
        """Tile rotation (seed 000 §4.3): idle nodes pull the next tiles (heaviest first), oldest frame
        first; when several are idle at once the fastest gets the heaviest, then the first freed."""
        idle = sorted((n for n in self.ready_nodes() if not n.outstanding), key=lambda n: (-n.speed, n.idle_since))
        for job in sorted(self.in_flight.values(), key=lambda j: j.frame_id):
            while job.pull_queue and idle:
                self._push(job, idle.pop(0), [job.pull_queue.popleft()])

    # ----------------------------------------------------------------- gathering
    def on_tile_message(self, link: NodeLink, message: bytes) -> None:
        """A binary tile from ``link``: parse, check, store; CPU time is accounted as receive/publish."""
        started = time.thread_time()
        published_before = self.cpu_ms["publish"]
        header, payload = unpack_tile(message)
        try:
            self.on_tile(link, header, bytes(payload))
        finally:
            spent = (time.thread_time() - started) * 1000.0
            self.cpu_ms["receive"] += spent - (self.cpu_ms["publish"] - published_before)

    def on_tile(self, link: NodeLink, header: TileHeader, payload: bytes) -> None:
        job = self.in_flight.get(header.frame_id)
        if job is None:
            log.debug("stale tile %d of frame %d from node %d dropped", header.tile_id, header.frame_id, link.node_id)
            return
        job.accept(link.node_id, header, payload)
        link.outstanding.pop((header.frame_id, header.tile_id), None)
        link.tiles_rendered += 1
        if not link.outstanding:
            link.idle_since = time.monotonic()
        if job.pull:
            self._pump_pull()
        if job.complete:
            del self.in_flight[job.frame_id]
            self._publish(job)
            self._awaiting_send[job.frame_id] = job
            for old in [k for k in self._awaiting_send if k < job.frame_id - 8]:
                del self._awaiting_send[old]
            self._maybe_take_timings(job)
            self.wake()

    def _maybe_take_timings(self, job: FrameJob) -> None:
        """Feed a complete frame's phases to the balancer once every tile's send time is in."""
        if not job.complete or not job.timings_complete:
            return
        for done in [k for k in self._awaiting_send if k <= job.frame_id]:
            del self._awaiting_send[done]
        timings = job.timings()
        self._last_timings = timings
        per_node: dict[int, dict[str, float]] = {}
        rects: dict[int, list[list[int]]] = {}
        for t in timings:
            phases = per_node.setdefault(t.node_id, {"render": 0.0, "readback": 0.0, "encode": 0.0, "send": 0.0})
            phases["render"] += t.render_ms
            phases["readback"] += t.readback_ms
            phases["encode"] += t.encode_ms
            phases["send"] += t.send_ms
            rects.setdefault(t.node_id, []).append(t.rect.as_list())
        counters = job.counters_by_node()
        for node_id, phases in per_node.items():
            link = self.nodes.get(node_id)
            if link is not None:
                link.last_phases, link.last_tiles = phases, rects[node_id]
                link.counters = counters.get(node_id, {})
        self.stats.record_balance({n: sum(p.values()) for n, p in per_node.items()})

    def _publish(self, job: FrameJob) -> None:
        if job.frame_id <= self.store.last_id:
            return
        started = time.thread_time()
        now = time.monotonic()
        frame = PublishedFrame(job.frame_id, job.camera, job.size,
                               [(t.rect, job.codec, t.rendered_by or 0, t.payload) for t in job.tiles], now)
        asyncio.get_running_loop().create_task(self.store.add(frame))
        if self.viewers.slots:
            self.viewers.publish_frame(frame.viewer_message)
        self.stats.record_publish(now, now - job.started_at)
        self.cpu_ms["publish"] += (time.thread_time() - started) * 1000.0

    async def _watchdog(self) -> None:
        """Drop a node that owes a tile for longer than ``tile_timeout_s``: its tiles move on."""
        while True:
            await asyncio.sleep(1.0)
            self._start_calibration()
            deadline = time.monotonic() - self.settings.tile_timeout_s
            for link in list(self.nodes.values()):
                if link.outstanding and min(link.outstanding.values()) < deadline:
                    log.warning("node %d (%s) owes a tile for over %.0f s: disconnecting it",
                                link.node_id, link.name, self.settings.tile_timeout_s)
                    link.close(1011, "tile timeout")
                    self.remove_node(link)

    # ----------------------------------------------------------------- reporting
    def describe(self) -> dict[str, Any]:
        return {
            "frame": self.store.last_id if self.store.last_id > 0 else 0,
            "fps": round(self.stats.fps(time.monotonic()), 2),
            "size": list(self.size),
            "balancer": self.balancer.name,
            "balancer_params": self.balancer.params,
            "imbalance": round(self.stats.imbalance, 4),
            "imbalance_avg": round(self.stats.imbalance_avg, 4),
            "latency_ms": round(self.stats.latency_ms, 2),
            "frames_in_flight": len(self.in_flight),
            "scene": self.settings.scene,
            "codec": self.settings.codec.name.lower(),
            "viewers": len(self.viewers.slots),
            "coordinator_cpu": {
                "frames": self.stats.frames_published,
                "receive_ms": round(self.cpu_ms["receive"], 3),
                "publish_ms": round(self.cpu_ms["publish"], 3),
                "process_ms": round(time.process_time() * 1000.0, 3),
                "viewer_bytes": self.viewers.bytes_published,
            },
            "nodes": [n.describe() for n in sorted(self.nodes.values(), key=lambda n: n.node_id)],
        }
