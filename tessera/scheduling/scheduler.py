"""The coordinator's frame scheduler without I/O (seed 004's APP stage; the sans-I/O pattern of
websockets' ``Protocol``): events in, actions out, clock readings passed in.

Events: the camera or the scene state changed, a balancer was chosen, a node joined / became
ready / left, a tile arrived, a tile's send time arrived, a tick. Actions (:meth:`drain`): send a
render message, cancel frames on a node, publish a frame, close a node. The asyncio service and
the virtual-clock benchmarks drive this same object.

What it decides:

* **Render on demand.** A frame starts only when something changed since the newest frame
  (camera, scene state, balancer, node set; a playing animation changes the state all the time),
  while the balancer settles (at most
  ``settle_frames`` more frames after a change, and only while the partition still moves), or
  when the still frame is owed: once nothing changed for ``still_delay_s``, one frame in the
  lossless ``still_codec`` (TurboVNC's lossless refresh; trame's still quality). Otherwise nothing
  renders.
* **Late camera binding** (seed 000 §4.5, seed 004: latency under two frames). A frame takes the
  newest camera when it starts, and it starts only when a node has nothing left to do, so its
  camera is fresh when the first node begins it; at most ``max_in_flight`` frames are in flight.
  When the state changes, frames that are superseded are dropped: a still frame, and any frame
  no node has begun (no tile arrived, none at the head of a node's queue). Nodes are told to
  drop their queued tiles of dropped frames; the scheduler stops waiting for them.
* **Late scene state binding** (issue 11; seed 004: a frame's dynamic data). A frame also takes
  the scene's state when it starts (:class:`tessera.scene.timeline.SceneTimeline`: the animation
  at the frame's scene time, the user's poses) as one version of the state log. Each render
  message carries that state: a delta on the version last sent to that node (messages reach a
  node in order), the full state when the node has none (it just joined) or that version is no
  longer kept. A node renders a tile with exactly that state, and its tile says which.
* **Never torn, never backwards.** A frame is published only when every tile arrived, all made
  for its one camera and its one scene state; publishing frame F drops every older frame still
  in flight.
* **Push and pull dispatch.** Push partitions go to their nodes at once; pull partitions (tile
  rotation, seed 000 §4.3) hand one tile at a time to an idle node, heaviest first, oldest frame
  first, the fastest idle node first. A node that leaves has its owed tiles re-dispatched.
* **Stragglers and failed tiles.** A node whose current tile is ``backup_factor`` times later than
  its expected time for it (its last frame's busy ms per pixel × the tile's pixels, or, for a node
  that has not finished a frame yet, the slowest rate any node has shown; at least
  ``backup_floor_s``) is suspect: the tiles it owes are copied to other nodes (MapReduce's backup
  tasks; the first copy back wins, the other is dropped) and it gets no new work until it answers
  again. A tile the node reports it could not render goes to another node; ``max_tile_failures``
  failures in a row close the node. A node silent past ``tile_timeout_s`` is closed.
* **Decomposition modes** (issue 10). ``sort-first``: tiles as above. ``hybrid`` (seed 000
  §4.4): the same tiles, the same balancers, but each render message asks for depth tiles and
  lists the frame's whole partition and the border strip, from which every node finds alone
  which chunks its tile owns (:mod:`tessera.decomposition.chunk_ownership`); the coordinator merges the strips.
  ``sort-last``: no balancer; each node holds a share of the scene (:mod:`tessera.decomposition.share_plan`:
  a node joining or leaving makes a new partition, frames in flight are dropped, each node is
  told to load its share of it, and frames start again once every share is loaded), and a frame
  is one whole-frame tile per share, each from the node holding it. Its tiles are never backed up
  nor moved to another node (no other node holds that share): a failing node's frames wait for
  the next partition.
* **Timing roll-up.** Per-node phases of each complete frame feed the stats; interactive frames'
  timings feed the balancer (a still frame's lossless encoding would skew it) from the moment the
  frame completes, so the next frame is partitioned with them; send times, which each node
  reports just after its tile, are added when they are in.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups, Tile, TileTiming
from tessera.balancers.partition import check_exact_cover
from tessera.balancers.projection import posed_groups, project_groups
from tessera.balancers.static import StaticBalancer
from tessera.decomposition.chunk_ownership import DEFAULT_DEPTH_STRIP
from tessera.decomposition.share_plan import ShareBook
from tessera.geometry import Camera, Rect
from tessera.scene.state import ObjectPatch, SceneState, StateDelta
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.frame_stats import FrameStats
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.messages import DepthRequest, Render, ShareSpec
from tessera.wire.protocol import NODE_PHASES, ProtocolError, TileHeader

#: Frames that stay in the awaiting-send table after completing (their ``tile_sent`` may lag).
AWAITING_SEND_FRAMES = 8
#: Slots for node indices in viewer frames (u16 on the wire).
MAX_NODE_SLOTS = 1 << 16
#: How often frames in flight are looked at for stragglers (s).
STRAGGLER_CHECK_S = 0.1
#: The decomposition modes (``--mode``); sort-first is the default.
MODES = ("sort-first", "hybrid", "sort-last")
#: Tiles of dropped frames a node is remembered to have owed (it may still send the one it was
#: on, or report the others skipped); the oldest are forgotten first.
DROPPED_MEMORY = 4096


@dataclass(frozen=True, slots=True)
class SchedulerConfig:
    """``codec``/``interactive_quality``: tiles while things change; ``still_codec`` (None: no still
    frame) and ``still_quality`` (JPEG only) once nothing changed for ``still_delay_s`` seconds;
    ``mode``: one of :data:`MODES`, ``depth_strip`` the hybrid's border strip (px)."""

    size: tuple[int, int]
    codec: Codec = Codec.JPEG
    interactive_quality: int = 60
    still_codec: Codec | None = Codec.PNG
    still_quality: int = 95
    max_in_flight: int = 2
    max_fps: float = 60.0
    still_delay_s: float = 0.2
    settle_frames: int = 2
    tile_timeout_s: float = 20.0
    backup_factor: float = 4.0
    backup_floor_s: float = 0.25
    max_tile_failures: int = 3
    mode: str = "sort-first"
    depth_strip: int = DEFAULT_DEPTH_STRIP

    def __post_init__(self) -> None:
        if self.mode not in MODES or self.depth_strip < 0:
            raise ValueError(f"mode must be one of {MODES} and depth_strip >= 0, got {self.mode}, {self.depth_strip}")
        if self.max_in_flight < 1:
            raise ValueError("max_in_flight must be >= 1")
        if not self.max_fps > 0.0:
            raise ValueError("max_fps must be > 0")
        if self.still_delay_s < 0.0 or self.settle_frames < 0 or not self.tile_timeout_s > 0.0:
            raise ValueError("still_delay_s and settle_frames must be >= 0, tile_timeout_s > 0")
        if not (self.backup_factor > 1.0 and self.backup_floor_s >= 0.0 and self.max_tile_failures >= 1):
            raise ValueError("backup_factor must be > 1, backup_floor_s >= 0, max_tile_failures >= 1")


@dataclass(frozen=True, slots=True)
class RenderTiles:
    """Send ``message`` to node ``node_id``."""

    node_id: int
    message: Render


@dataclass(frozen=True, slots=True)
class CancelFrames:
    """Tell node ``node_id`` to drop its queued tiles of ``frames`` (superseded)."""

    node_id: int
    frames: tuple[int, ...]


@dataclass(frozen=True, slots=True)
class PublishFrame:
    """``job`` is complete: show it (frames come in increasing id order)."""

    job: FrameJob


@dataclass(frozen=True, slots=True)
class CloseNode:
    """Disconnect node ``node_id`` (it has already been removed from the schedule)."""

    node_id: int
    code: int
    reason: str


@dataclass(frozen=True, slots=True)
class LoadShare:
    """Sort-last: tell node ``node_id`` to load ``share`` of the scene (and drop what it held)."""

    node_id: int
    share: ShareSpec


Action = RenderTiles | CancelFrames | PublishFrame | CloseNode | LoadShare


@dataclass
class NodeSchedule:
    """One node as the scheduler sees it. ``outstanding``: (frame id, tile id) → dispatch time, in
    the order the node works through them (its head is the tile it is on, since ``head_since``);
    ``slot``: the small index viewers see the node by; ``suspect``: overdue, given no work until it
    answers; ``ms_per_px``: its busy ms per pixel in its last complete frame; ``failures``: tiles
    failed in a row; ``dropped``: (frame id, tile id) it owed when their frame was dropped (the
    newest :data:`DROPPED_MEMORY`), so its late answers about them are told from tiles it never
    owed; ``state_sent``: the scene state version its last render message brought it to (None:
    none yet, or unsure after a failed tile); the rest is the last complete frame's roll-up."""

    node_id: int
    slot: int
    ready: bool = False
    speed: float = 1.0
    idle_since: float = 0.0
    head_since: float = 0.0
    suspect: bool = False
    ms_per_px: float | None = None
    failures: int = 0
    state_sent: int | None = None
    outstanding: dict[tuple[int, int], float] = field(default_factory=dict)
    dropped: dict[tuple[int, int], None] = field(default_factory=dict)
    last_tiles: list[list[int]] = field(default_factory=list)
    #: Where the node drew in its last complete frame, [x, y, w, h] each: its tiles (sort-first),
    #: the extent of each depth tile (a hybrid tile with the strip drawn in, the rect a sort-last
    #: share projects to; none for a share out of view).
    last_readback: list[list[int]] = field(default_factory=list)
    last_phases: dict[str, float] = field(default_factory=dict)
    counters: dict[str, Any] = field(default_factory=dict)
    tiles_rendered: int = 0

    @property
    def schedulable(self) -> bool:
        """Ready for work: its scene is loaded and it is not overdue."""
        return self.ready and not self.suspect

    @property
    def idle(self) -> bool:
        return self.schedulable and not self.outstanding


def tile_set(partition: Partition) -> frozenset[tuple[tuple[int, int, int, int], int | None]]:
    """The partition's (rect, node) pairs, order ignored (a pull list re-sorted is the same tiles)."""
    return frozenset(((t.rect.x, t.rect.y, t.rect.w, t.rect.h), t.node_id) for t in partition.tiles)


class FrameScheduler:
    """Frames in flight for one coordinator; see the module docstring. Every event takes ``now``
    (seconds on any monotonic clock) and may queue actions; :meth:`drain` returns them in order."""

    def __init__(self, config: SchedulerConfig, balancer: Balancer) -> None:
        self.config = config
        self.balancer = balancer
        self.nodes: dict[int, NodeSchedule] = {}
        self.camera: Camera | None = None
        #: The scene's objects, animations and state log (None: frames show the base pose).
        self.scene: SceneTimeline | None = None
        self.in_flight: dict[int, FrameJob] = {}
        self.stats = FrameStats()
        self.next_frame_id = 1
        self.last_published_id = 0
        self.frames_cancelled = 0
        self._actions: list[Action] = []
        self._version = 0
        self._changed_at = 0.0
        self._started_version = 0
        self._still_version = 0
        self._published_version = 0
        self._settle_left = 0
        self._inputs: dict[Hashable, int] = {}
        #: Projected primitive groups for a camera and the frame's scene state (None: the base pose)
        #: (seed 003 DPBP), for balancers that use them.
        self.groups_for: Callable[[Camera, SceneState | None], ProjectedGroups | None] | None = None
        self._partitions: list[Partition] = []
        self._last_partition_at: float | None = None
        self._last_timings: tuple[TileTiming, ...] = ()
        self._timings_frame_id = 0
        self.balancer_error: str | None = None
        self._awaiting_send: dict[int, FrameJob] = {}
        self._next_start_at = 0.0
        self._ready_nodes: list[NodeSchedule] | None = None
        self._idle: set[int] = set()
        self._next_straggler_check = 0.0
        self.backups = 0
        #: Sort-last: the data partitions and the shares the nodes hold (None in the other modes).
        self.shares = ShareBook() if config.mode == "sort-last" else None

    # ----------------------------------------------------------------- output
    def drain(self) -> list[Action]:
        """The actions queued since the last call, in the order they must be carried out."""
        actions, self._actions = self._actions, []
        return actions

    def next_deadline(self, now: float) -> float | None:
        """The earliest time a :meth:`tick` could do something (a start the frame-rate cap holds
        back, the still frame's quiet period, a tile timeout); None: only an event can."""
        times = []
        startable = len(self.in_flight) < self.config.max_in_flight and self._idle
        owed = self._owed(now, ignore_quiet=True) if startable else None
        if owed is not None:
            quiet_until = self._changed_at + self.config.still_delay_s if owed == "still" else now
            times.append(max(self._next_start_at, quiet_until))
        if self.in_flight:
            times.append(min(self._oldest_dispatch() + self.config.tile_timeout_s, self._next_straggler_check))
        return min(times) if times else None

    def _oldest_dispatch(self) -> float:
        """No tile owed was dispatched before this (the oldest frame in flight's start; tiles
        re-dispatched later only make it early, so a tick comes early, never late)."""
        return min(job.started_at for job in self.in_flight.values())

    @property
    def state_version(self) -> int:
        """Increases with every change that needs a new frame."""
        return self._version

    @property
    def settled(self) -> bool:
        """True when nothing is owed: the newest state was rendered, the still frame too."""
        return not self.in_flight and self._owed(float("inf")) is None

    # ----------------------------------------------------------------- state events
    def set_camera(self, camera: Camera, now: float, source: Hashable | None = None,
                   seq: int | None = None) -> int:
        """Make ``camera`` the newest (``seq``: the input sequence number of viewer ``source``);
        returns the id of the first frame that can show it."""
        self.camera = camera
        if source is not None and seq is not None:
            self._inputs[source] = seq
        first = self.next_frame_id
        self._changed(now, supersede=True)
        return first

    def invalidate(self, now: float) -> int:
        """The scene state changed (objects, animation, background): render it; returns the first
        frame id that can show it."""
        first = self.next_frame_id
        self._changed(now, supersede=True)
        return first

    def set_scene(self, scene: SceneTimeline, now: float) -> None:
        """Frames from now on show ``scene``'s state."""
        self.scene = scene
        self._changed(now, supersede=True)

    def set_objects(self, patches: Mapping[str, ObjectPatch], now: float) -> int:
        """Pose objects (:meth:`SceneTimeline.set_objects`); returns the first frame id that shows
        it. UnknownObjectError (and nothing changes) for a name that is not an object."""
        self._scene().set_objects(patches)
        return self.invalidate(now)

    def set_animation(self, now: float, playing: bool | None = None, time: float | None = None,
                      speed: float | None = None) -> int:
        """Play, pause, jump, change speed (:meth:`SceneTimeline.set_animation`); returns the first
        frame id that shows it. SceneStateError (and nothing changes) for a bad value."""
        self._scene().set_animation(now, playing, time, speed)
        return self.invalidate(now)

    def _scene(self) -> SceneTimeline:
        if self.scene is None:
            raise RuntimeError("no scene yet: no node has loaded it")
        return self.scene

    def set_balancer(self, balancer: Balancer, now: float) -> None:
        """Partition with ``balancer`` from the next frame."""
        self.balancer = balancer
        self._partitions.clear()
        self.stats.reset_imbalance()
        self._changed(now, supersede=False)

    def set_groups(self, boxes: np.ndarray, counts: np.ndarray, bounds: np.ndarray,
                   owners: np.ndarray | None = None) -> None:
        """The scene's world-space primitive groups (K, 6) at the base pose with primitive counts (K,),
        its bounds (2, 3) and each group's object ``owners`` (K,) (indices into the scene's objects;
        None: the groups never move), projected per frame for balancers that use them (seed 003
        DPBP): with a frame's state, each group moved with its object, hidden objects' groups
        dropped, near/far from the state's bounds (:func:`tessera.balancers.projection.posed_groups`)."""
        boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 6)
        counts = np.asarray(counts, dtype=np.float64).reshape(-1)
        bounds = np.asarray(bounds, dtype=np.float64)
        objects = None if owners is None else np.asarray(owners, dtype=np.int64).reshape(-1)
        size = self.config.size

        def groups_for(camera: Camera, state: SceneState | None) -> ProjectedGroups:
            if state is None or objects is None or self.scene is None:
                return project_groups(boxes, counts, camera, size, bounds)
            graph = self.scene.graph
            seen = graph.bounds(state)
            posed, weights = posed_groups(boxes, counts, objects, graph, state)
            return project_groups(posed, weights, camera, size, bounds if seen is None else seen)

        self.groups_for = groups_for

    def forget_source(self, source: Hashable) -> None:
        """A viewer left: its input numbers are no longer reported."""
        self._inputs.pop(source, None)

    # ----------------------------------------------------------------- node events
    def add_node(self, node_id: int, now: float) -> NodeSchedule:
        """A node connected (not ready until its scene is loaded)."""
        if node_id in self.nodes:
            raise ValueError(f"node {node_id} is already scheduled")
        used = {n.slot for n in self.nodes.values()}
        slot = next(i for i in range(MAX_NODE_SLOTS + 1) if i not in used)
        if slot >= MAX_NODE_SLOTS:
            raise ValueError(f"more than {MAX_NODE_SLOTS} nodes at once")
        node = NodeSchedule(node_id, slot, idle_since=now)
        self.nodes[node_id] = node
        if self.shares is not None:
            self._repartition(now)
        return node

    def node_ready(self, node_id: int, now: float, share: int | None = None) -> None:
        """The node loaded the scene (sort-last: its share of partition ``share``)."""
        node = self.nodes[node_id]
        node.ready, node.idle_since = True, now
        self._ready_nodes = None
        self._touch(node)
        if self.shares is not None and share is not None:
            self.shares.share_loaded(node_id, share)
        self._changed(now, supersede=False)

    def set_speed(self, node_id: int, speed: float) -> None:
        """Calibrated relative speed (seed 003 §1; slowest = 1), the balancers' node weight."""
        self.nodes[node_id].speed = float(speed)

    def remove_node(self, node_id: int, now: float) -> None:
        """The node is gone: its owed tiles go to the others (or their frames are dropped when no
        ready node is left)."""
        node = self.nodes.pop(node_id, None)
        if node is None:
            return
        node.outstanding.clear()
        self._ready_nodes = None
        self._idle.discard(node_id)
        if self.shares is not None:
            self.shares.forget(node_id)
            self._repartition(now)
            self._changed(now, supersede=False)
            return
        ready = self._ready()
        for job in list(self.in_flight.values()):
            owed = job.owed_by(node_id)
            if not owed:
                continue
            if not ready:
                self._cancel(job, now)
                continue
            if job.pull:
                for tile_id in reversed(owed):
                    job.tiles[tile_id].node_id = None
                    job.pull_queue.appendleft(tile_id)
            else:
                for tile_id in owed:
                    self._push(job, min(ready, key=lambda n: (len(n.outstanding), n.node_id)), [tile_id], now)
        if node.ready:
            self._changed(now, supersede=False)
        else:
            self._advance(now)

    # ----------------------------------------------------------------- tile events
    def tile_arrived(self, node_id: int, header: TileHeader, payload: bytes, now: float,
                     depth_tile: DecodedDepthTile | None = None) -> FrameJob | None:
        """A node's tile (a depth frame's with its ``depth_tile`` decoded); returns its frame, or
        None for a tile of a dropped frame (ignored). Raises ProtocolError when the node was not
        owed it (wrong frame, tile, rect or codec, or a second copy)."""
        node = self.nodes[node_id]
        key = (header.frame_id, header.tile_id)
        job = self.in_flight.get(header.frame_id)
        if job is None:
            if header.frame_id >= self.next_frame_id or header.frame_id < 1:
                raise ProtocolError(f"tile of frame {header.frame_id}, which was never dispatched")
            self._check_owed(node, key, "tile")
            self._answered(node, key, now)
            self._advance(now)
            return None
        tile = job.accept(node_id, header, payload, depth_tile)
        self._answered(node, key, now)
        if tile is None:
            self._advance(now)
            return None
        node.tiles_rendered += 1
        node.failures = 0
        if job.complete:
            self._complete(job, now)
        self._advance(now)
        return job

    def tile_sent(self, node_id: int, frame_id: int, tile_id: int, send_ms: float,
                  counters: dict[str, float | str] | None = None) -> None:
        """A node's ``tile_sent``: how long the tile took to send, and its per-tile counters."""
        job = self.in_flight.get(frame_id) or self._awaiting_send.get(frame_id)
        if job is not None:
            job.record_send(node_id, tile_id, max(float(send_ms), 0.0), counters)
            self._take_timings(job)

    def tile_failed(self, node_id: int, frame_id: int, tile_id: int, now: float) -> None:
        """The node could not render a tile it owes: it goes to another node (to this one again
        when it is alone); ``max_tile_failures`` in a row close the node. A tile of a frame dropped
        since is ignored; ProtocolError for one the node never owed (or already answered)."""
        node = self.nodes.get(node_id)
        key = (frame_id, tile_id)
        if node is None:
            return
        self._check_owed(node, key, "render_error for tile")
        node.state_sent = None   # the failure may be a state it could not apply: send it whole
        if key not in node.outstanding:
            return
        self._answered(node, key, now)
        node.failures += 1
        if node.failures >= self.config.max_tile_failures:
            self._actions.append(CloseNode(node_id, 1011, f"{node.failures} tiles failed in a row"))
            self.remove_node(node_id, now)
            return
        job = self.in_flight.get(frame_id)
        if job is not None and not job.tiles[tile_id].done and job.tiles[tile_id].node_id == node_id:
            if job.pull:
                job.tiles[tile_id].node_id = None
                job.pull_queue.appendleft(tile_id)
            else:
                others = [n for n in self._ready() if n is not node and self.shares is None] or [node]
                self._push(job, min(others, key=lambda n: (len(n.outstanding), n.node_id)), [tile_id], now)
        self._advance(now)

    def tiles_skipped(self, node_id: int, frame_id: int, tile_ids: Iterable[int]) -> None:
        """The node skipped these queued tiles of a frame it was told was dropped (its
        ``tiles_dropped``); ProtocolError for a tile that was not dropped while it owed it."""
        node = self.nodes.get(node_id)
        if node is None:
            return
        for tile_id in tile_ids:
            key = (frame_id, tile_id)
            if node.dropped.pop(key, ...) is not None:
                raise ProtocolError(f"tiles_dropped names tile {tile_id} of frame {frame_id}, "
                                    "which was not dropped from this node")

    def tick(self, now: float) -> None:
        """Time passed: back up stragglers' tiles, drop nodes that owe a tile for over
        ``tile_timeout_s``, start what is due."""
        if now >= self._next_straggler_check:
            self._next_straggler_check = now + STRAGGLER_CHECK_S
            self._back_up_stragglers(now)
        deadline = now - self.config.tile_timeout_s
        if self.in_flight and self._oldest_dispatch() < deadline:
            for node in list(self.nodes.values()):
                if node.outstanding and next(iter(node.outstanding.values())) < deadline:
                    self._actions.append(CloseNode(node.node_id, 1011, "tile timeout"))
                    self.remove_node(node.node_id, now)
        self._advance(now)

    # ----------------------------------------------------------------- internals
    def _ready(self) -> list[NodeSchedule]:
        """Schedulable nodes by id (kept until the node set or a node's state changes)."""
        if self._ready_nodes is None:
            self._ready_nodes = [n for n in sorted(self.nodes.values(), key=lambda n: n.node_id) if n.schedulable]
        return self._ready_nodes

    @staticmethod
    def _check_owed(node: NodeSchedule, key: tuple[int, int], what: str) -> None:
        """About ``key``, whose frame may be gone: the node must owe it, or have owed it when its
        frame was dropped (that memory is used up); ProtocolError otherwise."""
        if key not in node.outstanding and node.dropped.pop(key, ...) is not None:
            raise ProtocolError(f"{what} {key[1]} of frame {key[0]}, which this node does not owe "
                                "(never asked of it, or already answered)")

    def _answered(self, node: NodeSchedule, key: tuple[int, int], now: float) -> None:
        """``node`` sent back (or gave up) tile ``key``: it is no longer owed, and a suspect node that
        answers is trusted again."""
        if node.outstanding.pop(key, None) is not None:
            if node.outstanding:
                node.head_since = now
            else:
                node.idle_since = now
        if node.suspect:
            node.suspect = False
            self._ready_nodes = None
        self._touch(node)

    def _back_up_stragglers(self, now: float) -> None:
        """Copy the tiles of overdue nodes to the others (see the module docstring); not in
        sort-last, where no other node holds the share."""
        if self.shares is not None:
            return
        known = [n.ms_per_px for n in self.nodes.values() if n.ms_per_px is not None]
        slowest_known = max(known, default=None)
        for node in list(self.nodes.values()):
            rate = node.ms_per_px if node.ms_per_px is not None else slowest_known
            if node.suspect or rate is None:
                continue
            job, tile_id = next(((self.in_flight[f], t) for f, t in node.outstanding if f in self.in_flight),
                                (None, 0))
            if job is None:
                continue
            expected_s = rate * job.tiles[tile_id].rect.area / 1000.0
            if now - node.head_since <= max(self.config.backup_floor_s, self.config.backup_factor * expected_s):
                continue
            others = [n for n in self._ready() if n is not node]
            if not others:
                continue
            node.suspect = True
            self._ready_nodes = None
            self._touch(node)
            self.backups += 1
            for frame_id, tile_id in list(node.outstanding):
                owed = self.in_flight.get(frame_id)
                if owed is None or owed.tiles[tile_id].done or owed.tiles[tile_id].node_id != node.node_id:
                    continue
                owed.tiles[tile_id].earlier.add(node.node_id)
                self._push(owed, min(others, key=lambda n: (len(n.outstanding), n.node_id)), [tile_id], now)

    def _touch(self, node: NodeSchedule) -> None:
        """Keep ``_idle`` (ready nodes that owe nothing) in step after ``node``'s queue changed."""
        if node.idle:
            self._idle.add(node.node_id)
        else:
            self._idle.discard(node.node_id)

    def _changed(self, now: float, supersede: bool) -> None:
        self._version += 1
        self._changed_at = now
        self._settle_left = self.config.settle_frames
        if supersede:
            for job in list(self.in_flight.values()):
                if job.still or not self._begun(job):
                    self._cancel(job, now)
        self._advance(now)

    def _begun(self, job: FrameJob) -> bool:
        """True once a node works on ``job``: a tile arrived, a pulled tile went out, or one of its
        tiles heads a node's queue."""
        if job.tiles_done or (job.pull and len(job.pull_queue) < len(job.tiles)):
            return True
        return any(next(iter(n.outstanding))[0] == job.frame_id for n in self.nodes.values() if n.outstanding)

    def _cancel(self, job: FrameJob, now: float) -> None:
        """Drop ``job``: nodes that owe tiles of it are told to skip those still queued (the next
        tile a node owes counts as begun now: lenient, the node may still finish the dropped one)."""
        del self.in_flight[job.frame_id]
        self.frames_cancelled += 1
        for node in self.nodes.values():
            keys = [k for k in node.outstanding if k[0] == job.frame_id]
            if keys:
                for key in keys:
                    del node.outstanding[key]
                    node.dropped[key] = None
                while len(node.dropped) > DROPPED_MEMORY:
                    del node.dropped[next(iter(node.dropped))]
                node.head_since = now
                self._touch(node)
                self._actions.append(CancelFrames(node.node_id, (job.frame_id,)))

    def _owed(self, now: float, ignore_quiet: bool = False) -> str | None:
        """"interactive", "still" or None: the kind of frame the state asks for at ``now``."""
        if self.camera is None:
            return None
        if self._version > self._started_version or (self.scene is not None and self.scene.animating):
            return "interactive"
        if self._settle_left > 0 and self._unsettled():
            return "interactive"
        quiet = ignore_quiet or now >= self._changed_at + self.config.still_delay_s
        if self.config.still_codec is not None and self._still_version < self._version and quiet \
                and not self.in_flight:
            return "still"
        return None

    def _unsettled(self) -> bool:
        """The balancer's last two partitions differ (its edges still move), or it has made only one."""
        return len(self._partitions) < 2 or tile_set(self._partitions[0]) != tile_set(self._partitions[1])

    def _advance(self, now: float) -> None:
        """Hand out pulled tiles, then start every frame that is owed and allowed."""
        self._pump_pull(now)
        while True:
            ready = self._ready()
            if not ready or len(self.in_flight) >= self.config.max_in_flight or now < self._next_start_at:
                return
            if self.shares is not None and not self.shares.complete:
                return
            if not self._idle:
                return
            kind = self._owed(now)
            if kind is None:
                return
            self._start_frame(ready, now, still=kind == "still")
            self._pump_pull(now)

    def _start_frame(self, ready: list[NodeSchedule], now: float, still: bool) -> None:
        assert self.camera is not None
        state = self.scene.bind(now) if self.scene else None
        partition = self._partition(ready, now, self.camera, state)
        config = self.config
        if still:
            assert config.still_codec is not None
            codec, quality = config.still_codec, config.still_quality
            self._still_version, self._settle_left = self._version, 0
        else:
            codec, quality = config.codec, config.interactive_quality
            if self._started_version == self._version:
                self._settle_left -= 1
            self._started_version = self._version
        job = FrameJob.create(self.next_frame_id, self.camera, config.size, codec, quality, partition, now,
                              still=still, version=self._version, changed_at=self._changed_at,
                              inputs=dict(self._inputs), state=state,
                              depth=self._depth_request(partition))
        self.next_frame_id += 1
        self._next_start_at = now + 1.0 / config.max_fps
        self.in_flight[job.frame_id] = job
        if not job.pull:
            by_node: dict[int, list[int]] = {}
            for tile in job.tiles:
                assert tile.node_id is not None
                by_node.setdefault(tile.node_id, []).append(tile.tile_id)
            for node_id, tile_ids in by_node.items():
                self._push(job, self.nodes[node_id], tile_ids, now)

    def _depth_request(self, partition: Partition) -> DepthRequest | None:
        """What a frame of ``partition`` asks of the nodes in the configured mode (None: plain tiles)."""
        if self.config.mode == "hybrid":
            return DepthRequest(mode="hybrid", tiles=tuple(partition.rects), strip=self.config.depth_strip)
        if self.shares is not None and self.shares.plan is not None:
            return DepthRequest(mode="sort-last", share=self.shares.plan.version)
        return None

    def _repartition(self, now: float) -> None:
        """Sort-last: a new data partition over the nodes connected, weighted by their speeds; frames
        in flight are dropped (their shares are about to go) and every node is told its share."""
        assert self.shares is not None
        for job in list(self.in_flight.values()):
            self._cancel(job, now)
        plan = self.shares.repartition({n.node_id: n.speed for n in self.nodes.values()})
        if plan is not None:
            for index, node_id in enumerate(plan.holders):
                self._actions.append(LoadShare(node_id, ShareSpec(version=plan.version, index=index,
                                                                  weights=plan.weights)))

    def _partition(self, ready: list[NodeSchedule], now: float, camera: Camera,
                   state: SceneState | None = None) -> Partition:
        """The balancer's partition for the ready nodes (the static split if it fails), with the
        groups of ``camera`` in the frame's ``state``; in sort-last one whole-frame tile per share,
        to its holder."""
        if self.shares is not None and self.shares.plan is not None:
            frame = Rect(0, 0, *self.config.size)
            partition = Partition(tuple(Tile(frame, node_id) for node_id in self.shares.plan.holders))
            self._partitions = [*self._partitions[-1:], partition]
            return partition
        previous = self._partitions[-1] if self._partitions else None
        elapsed_ms = 0.0 if self._last_partition_at is None else (now - self._last_partition_at) * 1000.0
        inputs = BalanceInput(
            size=self.config.size, node_ids=tuple(n.node_id for n in ready), previous=previous,
            timings=self._last_timings, weights={n.node_id: n.speed for n in ready}, elapsed_ms=elapsed_ms,
            groups=self.groups_for(camera, state) if self.balancer.uses_groups and self.groups_for else None)
        try:
            partition = self.balancer.partition(inputs)
            check_exact_cover(partition.rects, self.config.size)
            strays = {t.node_id for t in partition.tiles if t.node_id is not None} - set(inputs.node_ids)
            if strays or (partition.pull and any(t.node_id is not None for t in partition.tiles)):
                raise ValueError(f"tiles assigned to nodes that are not ready: {sorted(strays)}")
        except Exception as exc:  # a balancer bug must not stop the frames: fall back to the static split
            partition = StaticBalancer().partition(inputs)
            self.balancer_error = f"{self.balancer.name}: {exc}"
        self._partitions = [*self._partitions[-1:], partition]
        self._last_partition_at = now
        return partition

    def _push(self, job: FrameJob, node: NodeSchedule, tile_ids: list[int], now: float) -> None:
        if not node.outstanding:
            node.head_since = now
        for tile_id in tile_ids:
            job.tiles[tile_id].node_id = node.node_id
            node.outstanding[(job.frame_id, tile_id)] = now
        self._idle.discard(node.node_id)
        self._actions.append(RenderTiles(node.node_id, job.render_message(tile_ids, self._state_for(node, job))))

    def _state_for(self, node: NodeSchedule, job: FrameJob) -> SceneState | StateDelta | None:
        """What brings ``node`` to ``job``'s state: a delta on the version it was sent last while the
        log keeps that one, else the whole state."""
        state = job.state
        if state is None or self.scene is None:
            return None
        base = None if node.state_sent is None else self.scene.log.get(node.state_sent)
        node.state_sent = state.version
        return state if base is None else state.delta_from(base)

    def _pump_pull(self, now: float) -> None:
        """Tile rotation (seed 000 §4.3): idle nodes pull the next tiles (heaviest first), oldest frame
        first; when several are idle at once the fastest gets the heaviest, then the first freed."""
        if not self._idle or not any(job.pull_queue for job in self.in_flight.values()):
            return
        idle = sorted((self.nodes[i] for i in self._idle), key=lambda n: (-n.speed, n.idle_since, n.node_id))
        for job in self.in_flight.values():
            while job.pull_queue and idle:
                self._push(job, idle.pop(0), [job.pull_queue.popleft()], now)

    def _complete(self, job: FrameJob, now: float) -> None:
        del self.in_flight[job.frame_id]
        for older in [j for j in self.in_flight.values() if j.frame_id < job.frame_id]:
            self._cancel(older, now)
        self.last_published_id = job.frame_id
        first_answer = job.version > self._published_version
        self._published_version = max(self._published_version, job.version)
        self.stats.record_publish(now, now - job.changed_at if first_answer and not job.still else None)
        self._actions.append(PublishFrame(job))
        self._awaiting_send[job.frame_id] = job
        for old in [k for k in self._awaiting_send if k < job.frame_id - AWAITING_SEND_FRAMES]:
            del self._awaiting_send[old]
        if not job.still and job.frame_id > self._timings_frame_id:
            self._last_timings, self._timings_frame_id = job.timings(), job.frame_id
        self._learn_rates(job)
        self._take_timings(job)

    def _learn_rates(self, job: FrameJob) -> None:
        """Each node's busy ms per pixel (render + read-back + encode) in ``job``: what a tile of
        it is expected to take, for spotting stragglers."""
        busy: dict[int, list[float]] = {}
        for tile in job.tiles:
            if tile.header is not None and tile.rendered_by is not None:
                spent = busy.setdefault(tile.rendered_by, [0.0, 0.0])
                spent[0] += tile.header.render_ms + tile.header.readback_ms + tile.header.encode_ms
                spent[1] += tile.rect.area
        for node_id, (ms, pixels) in busy.items():
            node = self.nodes.get(node_id)
            if node is not None and pixels > 0:
                node.ms_per_px = ms / pixels

    def _take_timings(self, job: FrameJob) -> None:
        """Roll a complete frame's phases up per node once every tile's send time is in; an
        interactive frame's timings also go to the balancer and the imbalance figures."""
        if not job.complete or not job.timings_complete or self._awaiting_send.pop(job.frame_id, None) is None:
            return
        timings = job.timings()
        per_node: dict[int, dict[str, float]] = {}
        rects: dict[int, list[list[int]]] = {}
        for t in timings:
            phases = per_node.setdefault(t.node_id, dict.fromkeys(NODE_PHASES, 0.0))
            for phase, ms in zip(NODE_PHASES, t.phase_ms, strict=True):
                phases[phase] += ms
            rects.setdefault(t.node_id, []).append(t.rect.as_list())
        counters = job.counters_by_node()
        readback = job.readback_by_node()
        for node_id, phases in per_node.items():
            node = self.nodes.get(node_id)
            if node is not None:
                node.last_phases, node.last_tiles = phases, rects[node_id]
                node.last_readback = readback.get(node_id, [])
                node.counters = counters.get(node_id, {})
        if not job.still and job.frame_id >= self._timings_frame_id:
            self._last_timings, self._timings_frame_id = timings, job.frame_id
            self.stats.record_balance({n: sum(p.values()) for n, p in per_node.items()})
