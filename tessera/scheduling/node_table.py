"""The nodes as the frame scheduler sees them: what each owes, since when, how fast it is, and
which are ready and idle (kept in step, asked on every event), and which want work. Pure bookkeeping.

**Dispatch ahead** (issue 19: nodes busy while work waits). A node that is given work only once it
owes nothing sits idle for the round trip between its last tile and the next render message
(plus the coordinator's turn), on every tile. So a node *wants work* (:meth:`NodeTable.wanting_work`)
when it is idle, or when it is on its last tile and that tile is expected to end within the
node's measured round trip (:attr:`NodeSchedule.lead_s`): the next frame's camera is bound that
much before the node could begin it, no earlier, so late camera binding loses almost nothing."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from tessera.geometry import Rect
from tessera.scheduling.frame_jobs import FrameJob
from tessera.wire.protocol import ProtocolError, TileHeader

#: Weight of a new round-trip sample in a node's smoothed lead time.
LEAD_SMOOTHING = 0.2
#: Longest lead (s): a node is never sent its next tile earlier than this before its last ends.
MAX_LEAD_S = 0.05

#: A node may owe its head tile this many times its longest recent tile time (dispatch to answer)
#: before the tile timeout closes it (never sooner than ``tile_timeout_s``).
TILE_TIMEOUT_FACTOR = 3.0
#: Each tile answered shrinks the longest recent tile time by this factor before it is compared.
TILE_TIME_DECAY = 0.9
#: The slowest a node is taken to draw the scene it holds, triangles a second: before its tiles of a
#: big scene were timed, a node may owe one for its triangles at this rate (a 33M-triangle share of
#: the 100M-triangle model: 66 s) before it counts as silent. The first frame of that model in
#: sort-last took three llvmpipe nodes sharing 2 loaded cores over 20 s (issue 31). A point cloud's
#: points count as triangles (issue 36): a still's sample of every point of a 100M-point survey took
#: a node's tile over 20 s on three nodes sharing 2 loaded cores, and the node was let go.
SLOWEST_TRIANGLES_PER_S = 500_000.0

#: Slots for node indices in viewer frames (u16 on the wire).
MAX_NODE_SLOTS = 1 << 16
#: Tiles of dropped frames a node is remembered to have owed (it may still send the one it was
#: on, or report the others skipped); the oldest are forgotten first.
DROPPED_MEMORY = 4096


@dataclass
class NodeSchedule:
    """One node as the scheduler sees it. ``outstanding``: (frame id, tile id) → dispatch time, in
    the order the node works through them (its head is the tile it is on, since ``head_since``);
    ``slot``: the small index viewers see the node by; ``suspect``: overdue, given no work until it
    answers; ``ms_per_px``: its busy ms per pixel in its last complete frame, or in its last tile
    that came too late to count (:meth:`learn_pace`); ``failures``: tiles
    failed in a row; ``dropped``: (frame id, tile id) it owed when their frame was dropped (the
    newest :data:`DROPPED_MEMORY`), so its late answers about them are told from tiles it never
    owed; ``state_sent``: the session and scene state version its last render message brought it
    to (a node keeps one state: another session's frame sends its state whole) (None:
    none yet, or unsure after a failed tile); ``lead_s``: how long before its last tile ends it is
    sent the next (its round trip: answer time − dispatch time − busy time of tiles sent to it
    while it owed nothing, smoothed); ``fresh``: such a tile in flight and when it went; ``local``:
    it connected from the coordinator's machine (loopback); ``host``: the machine it runs on, as it
    said (:attr:`tessera.wire.messages.NodeHello.host`); the rest is the last complete frame's roll-up."""

    node_id: int
    slot: int
    ready: bool = False
    speed: float = 1.0
    idle_since: float = 0.0
    head_since: float = 0.0
    suspect: bool = False
    ms_per_px: float | None = None
    failures: int = 0
    #: The frame and wall tile (``part_of``) of its last failed piece: the other pieces of that one
    #: drawing that fail with it are no more failures in a row (None: the last failure was no piece).
    failed_drawing: tuple[int, Rect] | None = None
    state_sent: tuple[str, int] | None = None
    lead_s: float | None = None
    fresh: tuple[tuple[int, int], float] | None = None
    local: bool = False
    host: str = ""
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
    #: Its longest recent tile, dispatch to answer (s), decayed by :data:`TILE_TIME_DECAY` a tile.
    tile_s: float = 0.0
    #: Times it lagged on a tile (:meth:`NodeTable.overdue`) and its tiles went to other nodes.
    backups: int = 0
    #: The most triangles of a scene (or share) it reported loaded.
    triangles: int = 0

    @property
    def schedulable(self) -> bool:
        """Ready for work: its scene is loaded and it is not overdue."""
        return self.ready and not self.suspect

    @property
    def idle(self) -> bool:
        return self.schedulable and not self.outstanding

    def learn_pace(self, header: TileHeader) -> None:
        """``ms_per_px`` from one tile's busy time (render + read-back + encode, ms, as the node
        measured it): a tile that came too late to count still tells how fast the node draws what
        it is given now, so a node whose share got heavier is not taken for a straggler frame after
        frame (its late tiles never join a complete frame that would teach it)."""
        if header.rect.area > 0:
            self.ms_per_px = (header.render_ms + header.readback_ms + header.encode_ms) / header.rect.area


class NodeTable:
    """The scheduled nodes by id (``nodes``), with the ready ones (schedulable, by id) and the idle
    ones (ready and owing nothing) kept in step: call :meth:`touch` after a node's queue or state
    changed."""

    def __init__(self) -> None:
        self.nodes: dict[int, NodeSchedule] = {}
        self.idle: set[int] = set()
        self._ready: list[NodeSchedule] | None = None

    def add(self, node_id: int, now: float) -> NodeSchedule:
        """A new node, not ready, with the lowest free slot; ValueError for a known id or too many."""
        if node_id in self.nodes:
            raise ValueError(f"node {node_id} is already scheduled")
        used = {n.slot for n in self.nodes.values()}
        slot = next(i for i in range(MAX_NODE_SLOTS + 1) if i not in used)
        if slot >= MAX_NODE_SLOTS:
            raise ValueError(f"more than {MAX_NODE_SLOTS} nodes at once")
        node = self.nodes[node_id] = NodeSchedule(node_id, slot, idle_since=now)
        return node

    def remove(self, node_id: int) -> NodeSchedule | None:
        """The node, gone from the table and owing nothing (None: unknown)."""
        node = self.nodes.pop(node_id, None)
        if node is not None:
            node.outstanding.clear()
            self._ready = None
            self.idle.discard(node_id)
        return node

    def ready(self) -> list[NodeSchedule]:
        """Schedulable nodes by id (kept until the node set or a node's state changes)."""
        if self._ready is None:
            self._ready = [n for n in sorted(self.nodes.values(), key=lambda n: n.node_id) if n.schedulable]
        return self._ready

    def holding(self, holders: set[int]) -> list[NodeSchedule]:
        """The ready nodes among ``holders`` (those that hold a session's scene), by id."""
        return [n for n in self.ready() if n.node_id in holders]

    def touch(self, node: NodeSchedule, state_changed: bool = False) -> None:
        """``node``'s queue changed (and, with ``state_changed``, whether it is ready or suspect)."""
        if state_changed:
            self._ready = None
        if node.idle:
            self.idle.add(node.node_id)
        else:
            self.idle.discard(node.node_id)

    def wanting_work(self, in_flight: Mapping[int, FrameJob], now: float) -> set[int]:
        """The ready nodes that want work at ``now``: the idle ones, and those whose last tile owed
        ends within their lead (see the module docstring)."""
        return self.idle | {n.node_id for n in self.nodes.values()
                            if (at := self._wants_from(n, in_flight)) is not None and at <= now}

    def next_wanting_at(self, in_flight: Mapping[int, FrameJob], now: float) -> float | None:
        """The earliest time after ``now`` a node busy now will want work (None: none will
        before it answers)."""
        times = [at for n in self.nodes.values() if (at := self._wants_from(n, in_flight)) is not None and at > now]
        return min(times, default=None)

    @staticmethod
    def _wants_from(node: NodeSchedule, in_flight: Mapping[int, FrameJob]) -> float | None:
        """When a schedulable node on its last tile wants its next: the tile's expected end (its
        busy ms per pixel × the tile's pixels after it began) less its lead; None when it owes
        more, or its rate or round trip is not measured yet."""
        if len(node.outstanding) != 1 or not node.schedulable or node.ms_per_px is None or node.lead_s is None:
            return None
        frame_id, tile_id = next(iter(node.outstanding))
        job = in_flight.get(frame_id)
        if job is None:
            return None
        expected_s = node.ms_per_px * job.tiles[tile_id].rect.area / 1000.0
        return node.head_since + expected_s - min(node.lead_s, MAX_LEAD_S)

    def assign(self, node: NodeSchedule, keys: list[tuple[int, int]], now: float) -> None:
        """``node`` owes the tiles ``keys`` (frame id, tile id) from ``now``."""
        if not node.outstanding:
            node.head_since = now
            node.fresh = (keys[0], now)
        for key in keys:
            node.outstanding[key] = now
        self.idle.discard(node.node_id)

    def drop(self, node: NodeSchedule, frame_id: int, now: float) -> bool:
        """Frame ``frame_id`` was dropped: ``node`` no longer owes its tiles (remembered as
        dropped); True when it owed any. When it was on one of them, its next tile counts as begun now."""
        keys = [k for k in node.outstanding if k[0] == frame_id]
        head = next(iter(node.outstanding), None)
        for key in keys:
            del node.outstanding[key]
            node.dropped[key] = None
        while len(node.dropped) > DROPPED_MEMORY:
            del node.dropped[next(iter(node.dropped))]
        if keys:
            if head in keys:
                node.head_since = now
            self.touch(node)
        return bool(keys)

    def overdue(self, in_flight: Mapping[int, FrameJob], factor: float, floor_s: float,
                now: float) -> list[NodeSchedule]:
        """Nodes not yet suspect whose current tile is ``factor`` times later than expected (its
        frame's ``expected_ms`` where known, else their last frame's busy ms per pixel × the pixels
        it draws, a wall's piece drawn with its whole tile; or for a node that has not finished a
        frame, the slowest rate any node has shown), at least ``floor_s`` late."""
        slowest_known = max((n.ms_per_px for n in self.nodes.values() if n.ms_per_px is not None), default=None)
        out = []
        for node in self.nodes.values():
            rate = node.ms_per_px if node.ms_per_px is not None else slowest_known
            if node.suspect or rate is None:
                continue
            head = next(((in_flight[f], t) for f, t in node.outstanding if f in in_flight), None)
            if head is None:
                continue
            job, tile_id = head
            expected_s = job.expected_ms / 1000.0 if job.expected_ms is not None \
                else rate * job.tiles[tile_id].drawn.area / 1000.0
            if now - node.head_since > max(floor_s, factor * expected_s):
                out.append(node)
        return out

    def timeout_at(self, floor_s: float) -> float | None:
        """When the first node owing a tile times out (:meth:`timed_out`); None: none owes one."""
        return min((next(iter(n.outstanding.values())) + self.allowed_s(n, floor_s)
                    for n in self.nodes.values() if n.outstanding), default=None)

    def timed_out(self, now: float, floor_s: float) -> list[NodeSchedule]:
        """Nodes that owe their first tile for longer than they are allowed (:meth:`allowed_s`)."""
        return [n for n in self.nodes.values()
                if n.outstanding and now - next(iter(n.outstanding.values())) > self.allowed_s(n, floor_s)]

    @staticmethod
    def allowed_s(node: NodeSchedule, floor_s: float) -> float:
        """How long ``node`` may owe a tile: :data:`TILE_TIMEOUT_FACTOR` times its longest recent
        tile, at least ``floor_s`` (``tile_timeout_s``) and its triangles at
        :data:`SLOWEST_TRIANGLES_PER_S`: a node drawing a share of a huge model in tens of seconds
        is not taken for a silent one, its first tile of it included."""
        return max(floor_s, TILE_TIMEOUT_FACTOR * node.tile_s, node.triangles / SLOWEST_TRIANGLES_PER_S)

    def heads(self, frame_id: int) -> bool:
        """A tile of frame ``frame_id`` heads a node's queue (the node is on it)."""
        return any(next(iter(n.outstanding))[0] == frame_id for n in self.nodes.values() if n.outstanding)

    @staticmethod
    def skipped(node: NodeSchedule, frame_id: int, tile_ids: Iterable[int]) -> None:
        """``node`` skipped these queued tiles of dropped frame ``frame_id`` (its ``tiles_dropped``);
        ProtocolError for a tile that was not dropped while it owed it."""
        for tile_id in tile_ids:
            if node.dropped.pop((frame_id, tile_id), ...) is not None:
                raise ProtocolError(f"tiles_dropped names tile {tile_id} of frame {frame_id}, "
                                    "which was not dropped from this node")

    @staticmethod
    def check_owed(node: NodeSchedule, key: tuple[int, int], what: str) -> None:
        """About ``key``, whose frame may be gone: the node must owe it, or have owed it when its
        frame was dropped (that memory is used up); ProtocolError otherwise."""
        if key not in node.outstanding and node.dropped.pop(key, ...) is not None:
            raise ProtocolError(f"{what} {key[1]} of frame {key[0]}, which this node does not owe "
                                "(never asked of it, or already answered)")

    def answered(self, node: NodeSchedule, key: tuple[int, int], now: float, busy_ms: float | None = None) -> None:
        """``node`` sent back (or gave up) tile ``key``, having been busy ``busy_ms`` on it (None: not
        known): it is no longer owed, and a suspect node that answers is trusted again."""
        if node.fresh is not None and node.fresh[0] == key:
            if busy_ms is not None:
                sample = max(now - node.fresh[1] - busy_ms / 1000.0, 0.0)
                node.lead_s = sample if node.lead_s is None else node.lead_s + LEAD_SMOOTHING * (sample - node.lead_s)
            node.fresh = None
        sent_at = node.outstanding.pop(key, None)
        if sent_at is not None:
            node.tile_s = max(now - sent_at, node.tile_s * TILE_TIME_DECAY)
            if node.outstanding:
                node.head_since = now
            else:
                node.idle_since = now
        was_suspect, node.suspect = node.suspect, False
        self.touch(node, state_changed=was_suspect)
