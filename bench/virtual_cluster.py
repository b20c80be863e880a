"""Render nodes on a virtual clock around the coordinator's own scheduler
(:class:`tessera.scheduling.scheduler.FrameScheduler`): the benchmarks and the balancer tests run the same
frame scheduling the live service runs, with tile costs from a model instead of GL.

Each virtual node works through the tiles sent to it in order; a tile of speed-1 cost c takes
c × sᵢ on node i (sᵢ its slowdown, as ``python -m node --slowdown``), and arrives at the scheduler
``network_ms`` after it is done; its ``tile_sent`` follows at once (send time 0). A cancel drops
the node's queued tiles of those frames (the tile it is on runs to the end). Tile costs come from
``measure(camera, rects)`` — real renders in ``bench.balance``, a cost map in the tests — asked
once per frame for all of its rects.

Cameras come either as fast as the cluster takes them (``dt_ms=None``: the next camera is set the
moment a frame starts with the newest one, so every camera is rendered once and the nodes never
wait for input; add ``max_fps`` to pace it) or at a fixed pace (``dt_ms``: camera i arrives at
i × dt_ms, frames take the newest one, as a user's input would).
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from tessera.balancers.base import Partition, ProjectedGroups, imbalance
from tessera.decomposition.balanced_tiles import tile_set
from tessera.geometry import Camera, Rect
from tessera.scheduling.actions import CancelFrames, PublishFrame, RenderTiles
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.codec import Codec
from tessera.wire.protocol import TileHeader


@dataclass(frozen=True, slots=True)
class Phases:
    """A tile's measured phases on a speed-1 node, milliseconds."""

    render_ms: float
    readback_ms: float = 0.0
    encode_ms: float = 0.0

    @property
    def busy_ms(self) -> float:
        return self.render_ms + self.readback_ms + self.encode_ms


#: ``measure(camera, rects)`` → each rect's phases at speed 1 (camera: its index in the camera list)
Measure = Callable[[int, Sequence[Rect]], Sequence[Phases]]


@dataclass(frozen=True)
class FrameRecord:
    """One published frame: the camera index it shows, its partition, each node's busy time on it
    (ms, slowdowns applied), frame time (its slowest node, ms), work (ms at speed 1), ideal frame
    time (work spread by node speed, ms), max/mean imbalance, efficiency = ideal / frame time,
    when it started and was published (ms of virtual time), the latency from its camera's input
    to publishing (ms), each tile's (begin, end, speed-1 cost) in ms and the node that drew it."""

    frame_id: int
    camera: int
    partition: Partition
    node_ms: dict[int, float]
    frame_ms: float
    work_ms: float
    ideal_ms: float
    imbalance: float
    efficiency: float
    started_ms: float
    done_ms: float
    latency_ms: float
    spans: tuple[tuple[float, float, float], ...] = ()
    nodes: tuple[int, ...] = ()


@dataclass
class VirtualNode:
    """A simulated node: its slowdown, the tiles sent to it in order (the head is the one it is on
    while ``busy``) as (frame id, tile id, rect, codec)."""

    slowdown: float
    queue: deque[tuple[int, int, Rect, Codec]] = field(default_factory=deque)
    busy: bool = False


class VirtualCluster:
    """Nodes ``slowdowns`` (node id → sᵢ) on a virtual clock driving a :class:`FrameScheduler`
    made with ``config`` and ``balancer``; ``weights`` are the calibrated node speeds given to the
    balancer (default 1); ``groups_at(camera)`` the projected primitive groups of a camera."""

    def __init__(self, config: SchedulerConfig, balancer, measure: Measure, slowdowns: Mapping[int, float],
                 weights: Mapping[int, float] | None = None, network_ms: float = 0.0,
                 groups_at: Callable[[int], ProjectedGroups] | None = None) -> None:
        if any(not s > 0.0 for s in slowdowns.values()):
            raise ValueError("slowdowns must be > 0")
        self.scheduler = FrameScheduler(config, balancer)
        self.measure, self.network_ms, self.weights = measure, network_ms, dict(weights or {})
        self.slowdowns = {int(n): float(s) for n, s in slowdowns.items()}
        self.nodes: dict[int, VirtualNode] = {}
        self.records: list[FrameRecord] = []
        self.now_s = 0.0
        self._events: list[tuple[float, int, str, object]] = []
        self._order = itertools.count()
        self._cameras: list[Camera] = []
        self._newest = -1
        self._input_ms: dict[int, float] = {}
        self._frame_phases: dict[int, dict[int, Phases]] = {}
        self._frame_camera: dict[int, int] = {}
        self._frame_started: dict[int, float] = {}
        self._spans: dict[int, dict[int, tuple[float, float, float]]] = {}
        self._seen_frame_id = 0
        self._tick_at: float | None = None
        self._nodes_at: Callable[[int], Sequence[int]] | None = None
        if groups_at is not None:
            self.scheduler.default.groups_for = lambda camera, state: groups_at(self._newest)
        for node_id in self.slowdowns:
            self._join(node_id)

    # ----------------------------------------------------------------- driving
    def run(self, cameras: Sequence[Camera], dt_ms: float | None = None,
            nodes_at: Callable[[int], Sequence[int]] | None = None) -> list[FrameRecord]:
        """Feed ``cameras`` (see the module docstring) until every frame owed is published;
        ``nodes_at(i)``: the nodes present when camera i is set (they join and leave then; only
        with ``dt_ms=None``). Returns the published frames in order."""
        if not cameras:
            raise ValueError("need at least one camera")
        self._cameras = list(cameras)
        self._nodes_at = nodes_at
        if dt_ms is None:
            self._input(0)
            self._after_event(paced=True)
        else:
            if nodes_at is not None:
                raise ValueError("nodes_at needs dt_ms=None")
            for index in range(len(cameras)):
                self._push(index * dt_ms / 1000.0, "input", index)
        while self._events:
            at, _, kind, payload = heapq.heappop(self._events)
            self.now_s = max(self.now_s, at)
            if kind == "input":
                self._input(int(payload))
            elif kind == "done":
                self._tile_done(int(payload))
            elif kind == "arrive":
                self._arrive(*payload)
            elif kind == "tick":
                self._tick_at = None
                self.scheduler.tick(self.now_s)
            self._after_event(paced=dt_ms is None)
        return self.records

    @property
    def now_ms(self) -> float:
        """The virtual clock in ms (it runs in seconds, the scheduler's unit, so that a tick at a
        deadline the scheduler gave is at that deadline exactly)."""
        return self.now_s * 1000.0

    def _push(self, at_s: float, kind: str, payload: object) -> None:
        heapq.heappush(self._events, (at_s, next(self._order), kind, payload))

    def _join(self, node_id: int) -> None:
        self.nodes[node_id] = VirtualNode(self.slowdowns[node_id])
        self.scheduler.add_node(node_id, self.now_s)
        self.scheduler.set_speed(node_id, self.weights.get(node_id, 1.0))
        self.scheduler.node_ready(node_id, self.now_s)

    def _input(self, index: int) -> None:
        if self._nodes_at is not None:
            present = set(self._nodes_at(index))
            for node_id in [n for n in self.nodes if n not in present]:
                del self.nodes[node_id]
                self.scheduler.remove_node(node_id, self.now_s)
            for node_id in sorted(present - set(self.nodes)):
                self._join(node_id)
        self._newest = index
        self._input_ms[index] = self.now_ms
        self.scheduler.set_camera(self._cameras[index], self.now_s)

    def _after_event(self, paced: bool) -> None:
        """Carry out the scheduler's actions; feed the next camera when paced by frame starts;
        keep one tick queued for the scheduler's next deadline."""
        while True:
            for action in self.scheduler.drain():
                if isinstance(action, RenderTiles):
                    self._receive_render(action)
                elif isinstance(action, CancelFrames):
                    node = self.nodes.get(action.node_id)
                    if node is not None:
                        self._cancel_queued(node, action.frames)
                elif isinstance(action, PublishFrame):
                    self._record(action.job)
            if not (paced and self._feed_next_camera()):
                break
        deadline = self.scheduler.next_deadline(self.now_s)
        if deadline is not None:
            at = max(deadline, self.now_s)
            if self._tick_at is None or at < self._tick_at:
                self._tick_at = at
                self._push(at, "tick", None)

    def _feed_next_camera(self) -> bool:
        """The newest camera's frame started: set the next camera now (returns whether it did)."""
        started = [f for f, c in self._frame_camera.items() if f > self._seen_frame_id and c == self._newest]
        self._seen_frame_id = max(self._frame_camera, default=0)
        if not started or self._newest + 1 >= len(self._cameras):
            return False
        self._input(self._newest + 1)
        return True

    # ----------------------------------------------------------------- nodes
    def _receive_render(self, action: RenderTiles) -> None:
        message = action.message
        frame_id = message.frame
        if frame_id not in self._frame_camera:
            job = self.scheduler.in_flight[frame_id]
            camera = self._newest
            self._frame_camera[frame_id] = camera
            self._frame_started[frame_id] = self.now_ms
            rects = [t.rect for t in job.tiles]
            self._frame_phases[frame_id] = dict(enumerate(self.measure(camera, rects)))
        node = self.nodes[action.node_id]
        node.queue.extend((frame_id, t.tile, t.rect, message.codec) for t in message.tiles)
        if not node.busy:
            self._start_next(action.node_id)

    @staticmethod
    def _cancel_queued(node: VirtualNode, frames: tuple[int, ...]) -> None:
        """Drop the node's queued tiles of ``frames``; the tile it is on (the head) runs to the end."""
        running = [node.queue.popleft()] if node.busy and node.queue else []
        node.queue = deque([*running, *(t for t in node.queue if t[0] not in frames)])

    def _start_next(self, node_id: int) -> None:
        node = self.nodes[node_id]
        if not node.queue:
            node.busy = False
            return
        frame_id, tile_id, _, _ = node.queue[0]
        phases = self._frame_phases[frame_id][tile_id]
        busy_ms = phases.busy_ms * node.slowdown
        self._spans.setdefault(frame_id, {})[tile_id] = (self.now_ms, self.now_ms + busy_ms, phases.busy_ms)
        node.busy = True
        self._push(self.now_s + busy_ms / 1000.0, "done", node_id)

    def _tile_done(self, node_id: int) -> None:
        node = self.nodes.get(node_id)
        if node is None:
            return
        frame_id, tile_id, rect, codec = node.queue.popleft()
        p, s = self._frame_phases[frame_id][tile_id], node.slowdown
        header = TileHeader(frame_id, tile_id, rect, codec, p.render_ms * s, p.readback_ms * s, p.encode_ms * s)
        self._push(self.now_s + self.network_ms / 1000.0, "arrive", (node_id, header))
        self._start_next(node_id)

    def _arrive(self, node_id: int, header: TileHeader) -> None:
        if node_id not in self.scheduler.nodes:
            return
        self.scheduler.tile_arrived(node_id, header, b"", self.now_s)
        self.scheduler.tile_sent(node_id, header.frame_id, header.tile_id, 0.0)

    # ----------------------------------------------------------------- records
    def _record(self, job: FrameJob) -> None:
        phases = self._frame_phases[job.frame_id]
        node_ms: dict[int, float] = dict.fromkeys(self.nodes, 0.0)
        drawn_by: list[int] = []
        for tile in job.tiles:
            assert tile.header is not None and tile.rendered_by is not None
            drawn_by.append(tile.rendered_by)
            busy = tile.header.render_ms + tile.header.readback_ms + tile.header.encode_ms
            node_ms[tile.rendered_by] = node_ms.get(tile.rendered_by, 0.0) + busy
        work = sum(p.busy_ms for p in phases.values())
        ideal = work / sum(1.0 / self.nodes[n].slowdown for n in node_ms if n in self.nodes)
        frame_ms = max(node_ms.values())
        camera = self._frame_camera[job.frame_id]
        spans = self._spans.pop(job.frame_id, {})
        assert job.partition is not None
        self.records.append(FrameRecord(
            job.frame_id, camera, job.partition, node_ms, frame_ms, work, ideal, imbalance(node_ms),
            ideal / frame_ms if frame_ms > 0.0 else 1.0, self._frame_started[job.frame_id], self.now_ms,
            self.now_ms - self._input_ms[camera], tuple(spans[t.tile_id] for t in job.tiles),
            tuple(drawn_by)))


def run_path(balancer, measure: Measure, cameras: Sequence[Camera], size: tuple[int, int],
             slowdowns: Mapping[int, float], weights: Mapping[int, float] | None = None, in_flight: int = 2,
             groups_at: Callable[[int], ProjectedGroups] | None = None, max_fps: float = 1e9,
             nodes_at: Callable[[int], Sequence[int]] | None = None) -> tuple[list[FrameRecord], VirtualCluster]:
    """Every camera rendered once, as fast as the cluster goes (paced at ``max_fps``), with
    ``in_flight`` frames in flight and no still frame: the balancing benchmarks' run."""
    config = SchedulerConfig(size=size, max_in_flight=in_flight, max_fps=max_fps, still_codec=None, settle_frames=0,
                             tile_timeout_s=1e9)
    cluster = VirtualCluster(config, balancer, measure, slowdowns, weights, groups_at=groups_at)
    return cluster.run(cameras, nodes_at=nodes_at), cluster


def summarize(records: Sequence[FrameRecord], skip: int = 10) -> dict[str, float | int]:
    """Figures over the frames after the first ``skip``: mean and 95th percentile of imbalance,
    mean efficiency, repartitions (frames whose tiles differ from the frame before's), frames,
    mean frame time and work (ms), and the pipelined efficiency and frame time over the window
    from the last left-out frame's publication to the last but one: the kept frames' work inside
    the window as ideal ms (a tile's cost × its frame's ideal / work, the part of its span inside)
    over the window (work of frames dropped unpublished does not count); NaN with fewer than 2
    kept frames."""
    kept = list(records[skip:])
    if not kept:
        raise ValueError(f"need more than {skip} frames to summarize, got {len(records)}")
    ratios = np.array([r.imbalance for r in kept])
    start = records[skip - 1].done_ms if skip else 0.0
    stop = kept[-2].done_ms if len(kept) > 1 else start
    elapsed = stop - start
    ideal_inside = sum(cost * r.ideal_ms / r.work_ms * max(min(end, stop) - max(begin, start), 0.0) / (end - begin)
                       for r in kept if r.work_ms > 0.0 for begin, end, cost in r.spans if end > begin)
    repartitions = sum(tile_set(records[i].partition) != tile_set(records[i - 1].partition)
                       for i in range(max(skip, 1), len(records)))
    return {"imbalance_mean": float(ratios.mean()), "imbalance_p95": float(np.percentile(ratios, 95)),
            "efficiency": float(np.mean([r.efficiency for r in kept])), "repartitions": int(repartitions),
            "frames": len(kept), "frame_ms": float(np.mean([r.frame_ms for r in kept])),
            "work_ms": float(np.mean([r.work_ms for r in kept])),
            "efficiency_pipelined": ideal_inside / elapsed if elapsed > 0.0 else float("nan"),
            "frame_ms_pipelined": elapsed / (len(kept) - 1) if elapsed > 0.0 else float("nan"),
            "latency_ms": float(np.mean([r.latency_ms for r in kept]))}


# --------------------------------------------------------------------------------- cost-map model


def summed_area(cost: np.ndarray) -> np.ndarray:
    """(H+1, W+1) summed-area table of an (H, W) cost map, zero first row and column."""
    table = np.zeros((cost.shape[0] + 1, cost.shape[1] + 1))
    table[1:, 1:] = cost.cumsum(0).cumsum(1)
    return table


def rect_sums(table: np.ndarray, rects: Sequence[Rect]) -> np.ndarray:
    """Sum of the cost map over each rect (R,), from its summed-area table."""
    r = np.array([[t.x, t.y, t.x1, t.y1] for t in rects], dtype=np.int64).reshape(-1, 4)
    return table[r[:, 3], r[:, 2]] - table[r[:, 1], r[:, 2]] - table[r[:, 3], r[:, 0]] + table[r[:, 1], r[:, 0]]


def map_measure(cost_at: Callable[[int], np.ndarray], noise: float = 0.0, seed: int = 0) -> Measure:
    """``measure`` from per-camera (H, W) cost maps in ms per pixel at speed 1: a tile's render
    time is the map's sum over it, × (1 + ``noise`` × a seeded standard normal draw, ≥ 0)."""
    rng = np.random.default_rng(seed)

    def measure(camera: int, rects: Sequence[Rect]) -> list[Phases]:
        costs = rect_sums(summed_area(cost_at(camera)), rects)
        if noise:
            costs = costs * np.maximum(1.0 + noise * rng.standard_normal(len(costs)), 0.0)
        return [Phases(float(c)) for c in costs]

    return measure
