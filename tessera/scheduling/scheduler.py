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
  when the still frame is owed: once nothing changed for ``still_delay_ms``, frames in the
  lossless ``still_codec`` (TurboVNC's lossless refresh; trame's still quality): the progressive
  still's jittered samples (``still_samples``, or until it converges), one frame after the other, the next sent ahead to
  nodes ending their tile of the one before (:mod:`tessera.scheduling.refinement`; their adapter
  accumulates them and shows the mean, so when every node is on the coordinator's machine the
  samples' tiles travel raw: no PNG to encode on the nodes nor to check and decode on the
  coordinator; a frame no larger than the coordinator's ``size``, whose node messages allow four raw
  frames). Otherwise nothing renders. So do the interactive tiles of a session every viewer takes
  as video (issue 21): the encoder's source, without JPEG's loss.
* **Late camera binding** (seed 000 §4.5, seed 004: latency under two frames). A frame takes the
  newest camera when it starts, and it starts only when a node wants work — it has nothing left
  to do, or its last tile ends within its round trip (dispatch ahead,
  :mod:`tessera.scheduling.node_table`) — so its camera is fresh when the first node begins it
  and no node idles for the round trip; at most ``max_in_flight`` frames are in flight.
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
* **Decomposition modes** (issue 10): the scheduler holds one
  :class:`tessera.decomposition.mode.DecompositionMode` (``--mode``) and asks it what a frame is
  cut into, what its render messages ask of the nodes, what a tile must be and what viewers get
  of a complete frame; whether tiles may move between nodes (backups, failed tiles); and, when
  the node set changes, what each node must load (sort-last: a new data partition, frames in
  flight dropped, no frame until every share is loaded).
* **Sessions** (issue 19). Every frame belongs to a session (:class:`SessionFrames`: its own
  size, mode and balancer, camera, scene state and frames); the nodes are shared. Frame ids are
  unique across sessions, so a node's queue may hold tiles of several. A frame of a session
  starts only when a node that holds its scene has nothing left to do (or, while only some
  nodes hold it and none of them is free, when another node is: :meth:`FrameScheduler._free_for`);
  when several sessions owe a frame, the one that has had least node time goes first
  (:class:`FairShare`; while only some nodes hold a session's scene, its time on them counts
  as many times as they are fewer than the ready nodes, :meth:`FrameScheduler._scarcity`, and
  its frames go to them in pieces one at a time, :meth:`FrameScheduler._pieces`). The methods
  that act on one session take its id and default to :data:`DEFAULT_SESSION`.
* **Timing roll-up.** Per-node phases of each complete frame feed the stats; interactive frames'
  timings feed the balancer (a still frame's lossless encoding would skew it) from the moment the
  frame completes, so the next frame is partitioned with them; send times, which each node
  reports just after its tile, are added when they are in.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from tessera.balancers.base import Balancer
from tessera.decomposition.chunk_ownership import DEFAULT_DEPTH_STRIP
from tessera.decomposition.mode import ViewerTile
from tessera.decomposition.modes import MODES
from tessera.geometry import Camera
from tessera.scene.state import ObjectPatch
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.actions import (
    Action,
    BalancerFailed,
    CancelFrames,
    CloseNode,
    LoadScene,
    PublishFrame,
    RenderTiles,
)
from tessera.scheduling.fair_share import FairShare
from tessera.scheduling.frame_jobs import DEFAULT_SESSION, FrameJob
from tessera.scheduling.lod_control import (
    DEFAULT_LOD_ERROR_PX,
    DEFAULT_LOD_MAX_ERROR_PX,
    DEFAULT_TARGET_FPS,
    LodControl,
)
from tessera.scheduling.node_table import NodeSchedule, NodeTable
from tessera.scheduling.refinement import DEFAULT_MAX_STILL_SAMPLES, DEFAULT_STILL_TARGET_DB, StillPlan
from tessera.scheduling.render_demand import STILL
from tessera.scheduling.session_frames import SessionFrames
from tessera.video.budget import full_analysis
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.protocol import NO_NODE_SLOT, ProtocolError, TileHeader

#: Frames that stay in the awaiting-send table after completing (their ``tile_sent`` may lag).
AWAITING_SEND_FRAMES = 8
#: How often frames in flight are looked at for stragglers (s).
STRAGGLER_CHECK_S = 0.1
#: While few nodes hold a session's scene, its frames are cut into pieces expected to take about
#: this long (ms of node time) each on the nodes that hold it, at most :data:`MAX_PIECES`; its
#: first frame, whose cost is not known yet, into :data:`FIRST_FRAME_PIECES`.
PIECE_MS = 40.0
MAX_PIECES = 8
FIRST_FRAME_PIECES = 4


@dataclass(frozen=True, slots=True)
class SchedulerConfig:
    """What the scheduler is told, with the defaults the coordinator's settings take over
    (:class:`server.settings.Settings` extends this class; nothing is defined twice but
    ``still_samples``: 1 here, one still frame; the coordinator's is adaptive).

    ``size`` (w, h) px; ``codec``/``interactive_quality``: tiles while things change;
    ``still_codec`` (None: no still frame) and ``still_quality`` (JPEG only) once nothing changed
    for ``still_delay_ms``, ``still_samples`` jittered frames accumulated into the still (0:
    adaptive, until its estimate reaches ``still_target_db``, at most ``still_samples_max``);
    ``mode``: one of :data:`MODES`, ``depth_strip`` the hybrid's border strip (px);
    ``background``: the clear colour, linear RGB in [0, 1] (None: the default), which the depth
    modes' merge paints where no node drew; ``lod_error_px``, ``lod_max_error_px`` and
    ``target_fps``: a moving frame's levels-of-detail bound (:mod:`tessera.scheduling.lod_control`)."""

    size: tuple[int, int] = (1280, 720)
    codec: Codec = Codec.JPEG
    interactive_quality: int = 60
    still_codec: Codec | None = Codec.PNG
    still_quality: int = 95
    still_delay_ms: float = 200.0
    still_samples: int = 1
    still_samples_max: int = DEFAULT_MAX_STILL_SAMPLES
    still_target_db: float = DEFAULT_STILL_TARGET_DB
    settle_frames: int = 2
    max_in_flight: int = 2
    max_fps: float = 60.0
    tile_timeout_s: float = 20.0
    backup_factor: float = 4.0
    backup_floor_s: float = 0.25
    max_tile_failures: int = 3
    mode: str = "sort-first"
    depth_strip: int = DEFAULT_DEPTH_STRIP
    background: tuple[float, float, float] | None = None
    lod_error_px: float = DEFAULT_LOD_ERROR_PX
    lod_max_error_px: float = DEFAULT_LOD_MAX_ERROR_PX
    target_fps: float = DEFAULT_TARGET_FPS

    def __post_init__(self) -> None:
        if self.mode not in MODES or self.depth_strip < 0:
            raise ValueError(f"mode must be one of {MODES} and depth_strip >= 0, got {self.mode}, {self.depth_strip}")
        if self.max_in_flight < 1:
            raise ValueError("max_in_flight must be >= 1")
        LodControl(self.lod_error_px, self.lod_max_error_px, self.target_fps)   # raises for a bad bound
        if not self.max_fps > 0.0:
            raise ValueError("max_fps must be > 0")
        assert self.still_plan   # its checks raise ValueError
        if self.still_delay_ms < 0.0 or self.settle_frames < 0 or not self.tile_timeout_s > 0.0:
            raise ValueError("still_delay_ms and settle_frames must be >= 0, tile_timeout_s > 0")
        if not (self.backup_factor > 1.0 and self.backup_floor_s >= 0.0 and self.max_tile_failures >= 1):
            raise ValueError("backup_factor must be > 1, backup_floor_s >= 0, max_tile_failures >= 1")

    @property
    def still_plan(self) -> StillPlan:
        """How a still is sampled."""
        return StillPlan(self.still_samples, self.still_samples_max, self.still_target_db)

    @property
    def still_delay_s(self) -> float:
        return self.still_delay_ms / 1000.0

    def scheduler_config(self) -> SchedulerConfig:
        """The scheduler's part of these settings (of a subclass: its own fields left out)."""
        return SchedulerConfig(**{name: getattr(self, name) for name in SchedulerConfig.__dataclass_fields__})


class FrameScheduler:
    """Frames in flight for one coordinator; see the module docstring. Every event takes ``now``
    (seconds on any monotonic clock) and may queue actions; :meth:`drain` returns them in order.
    ``config``, ``balancer`` and ``scene`` (the spec nodes load; None: whatever the adapter's own
    scene is) make the default session; sessions share ``config``'s timeouts."""

    def __init__(self, config: SchedulerConfig, balancer: Balancer, scene: str | None = None) -> None:
        self.config = config
        self.sessions: dict[str, SessionFrames] = {}
        self.fair = FairShare()
        self.in_flight: dict[int, FrameJob] = {}
        self.next_frame_id = 1
        self.last_published_id = 0
        self.frames_cancelled = 0
        self.table = NodeTable()
        self.nodes = self.table.nodes
        self._actions: list[Action] = []
        self._next_straggler_check = 0.0
        self.backups = 0
        self.add_session(DEFAULT_SESSION, config, balancer, scene, 0.0)

    # ----------------------------------------------------------------- the default session
    @property
    def default(self) -> SessionFrames:
        """The default session (the routes without a session id act on it)."""
        return self.sessions[DEFAULT_SESSION]

    # ----------------------------------------------------------------- output
    def drain(self) -> list[Action]:
        """The actions queued since the last call, in the order they must be carried out."""
        actions, self._actions = self._actions, []
        return actions

    def next_deadline(self, now: float) -> float | None:
        """The earliest time a :meth:`tick` could do something (a start the frame-rate cap holds
        back, the still frame's quiet period, a tile timeout); None: only an event can."""
        free = self._wanting_work(now)
        if len(self.sessions) == 1:   # one session is always in turn
            times = [at] if (at := self.default.start_due(now, self._free_for(self.default, free))) is not None else []
        else:
            backlogged = [s.id for s in self.sessions.values() if s.frames or s.owed(now) is not None]
            times = [at for s in self.sessions.values()
                     if (at := s.start_due(now, self._free_for(s, free))) is not None
                     and self.fair.in_turn(s.id, backlogged)]
        if self.in_flight:
            times.append(min(self._oldest_dispatch() + self.config.tile_timeout_s, self._next_straggler_check))
            if any(self._goes_ahead(s) for s in self.sessions.values()) and (
                    at := self.table.next_wanting_at(self.in_flight, now)) is not None:
                times.append(at)
        return min(times) if times else None

    def _oldest_dispatch(self) -> float:
        """No tile owed was dispatched before this (the oldest frame in flight's start; tiles
        re-dispatched later only make it early, so a tick comes early, never late)."""
        return min(job.started_at for job in self.in_flight.values())

    # ----------------------------------------------------------------- sessions
    def add_session(self, session_id: str, config: SchedulerConfig, balancer: Balancer, scene_key: str | None,
                    now: float, weight: float = 1.0) -> SessionFrames:
        """A new session of ``config``'s size, mode and codecs, whose nodes load ``scene_key``
        (None: the coordinator's scene); every node connected is told to load it."""
        if session_id in self.sessions:
            raise ValueError(f"session {session_id!r} exists already")
        session = self.sessions[session_id] = SessionFrames(session_id, config, balancer, scene_key)
        self.fair.add(session_id, weight)
        if self.nodes:
            self._repartition(session, now, force=True)
        return session

    def remove_session(self, session_id: str, now: float) -> None:
        """The session is closed: its frames are dropped (nodes skip their tiles)."""
        session = self.sessions.pop(session_id, None)
        if session is None:
            return
        for job in list(session.frames.values()):
            self._cancel(job, now)
        self.fair.remove(session_id)
        self._advance(now)

    def resize(self, size: tuple[int, int], now: float, session_id: str = DEFAULT_SESSION) -> int:
        """The session's frames are ``size`` (w, h) from now on; returns the first frame id of that size."""
        session = self.sessions[session_id]
        for job in list(session.frames.values()):
            self._cancel(job, now)
        session.resize(size)
        return self._changed(session, now, supersede=True)

    # ----------------------------------------------------------------- state events
    def set_camera(self, camera: Camera, now: float, source: Hashable | None = None, seq: int | None = None,
                   session_id: str = DEFAULT_SESSION) -> int:
        """Make ``camera`` the newest (``seq``: the input sequence number of viewer ``source``);
        returns the id of the first frame that can show it."""
        session = self.sessions[session_id]
        session.camera = camera
        if source is not None and seq is not None:
            session.inputs[source] = seq
        return self._changed(session, now, supersede=True)

    def invalidate(self, now: float, session_id: str = DEFAULT_SESSION) -> int:
        """The scene state changed (objects, animation, background): render it; returns the first
        frame id that can show it."""
        return self._changed(self.sessions[session_id], now, supersede=True)

    def set_scene(self, scene: SceneTimeline, now: float, session_id: str = DEFAULT_SESSION) -> None:
        """Frames from now on show ``scene``'s state."""
        self.sessions[session_id].scene = scene
        self._changed(self.sessions[session_id], now, supersede=True)

    def set_objects(self, patches: Mapping[str, ObjectPatch], now: float, session_id: str = DEFAULT_SESSION) -> int:
        """Pose objects (:meth:`SceneTimeline.set_objects`); returns the first frame id that shows
        it. UnknownObjectError (and nothing changes) for a name that is not an object."""
        self.sessions[session_id].timeline().set_objects(patches)
        return self.invalidate(now, session_id)

    def set_animation(self, now: float, playing: bool | None = None, time: float | None = None,
                      speed: float | None = None, session_id: str = DEFAULT_SESSION) -> int:
        """Play, pause, jump, change speed (:meth:`SceneTimeline.set_animation`); returns the first
        frame id that shows it. SceneStateError (and nothing changes) for a bad value."""
        self.sessions[session_id].timeline().set_animation(now, playing, time, speed)
        return self.invalidate(now, session_id)

    def set_balancer(self, balancer: Balancer, now: float, session_id: str = DEFAULT_SESSION) -> None:
        """Partition with ``balancer`` from the next frame."""
        session = self.sessions[session_id]
        session.mode.tiles.set_balancer(balancer)
        session.stats.reset_imbalance()
        self._changed(session, now, supersede=False)

    def set_groups(self, boxes: np.ndarray, counts: np.ndarray, bounds: np.ndarray,
                   owners: np.ndarray | None = None, session_id: str = DEFAULT_SESSION) -> None:
        """The scene's primitive groups (:meth:`SessionFrames.set_groups`)."""
        self.sessions[session_id].set_groups(boxes, counts, bounds, owners)

    # ----------------------------------------------------------------- node events
    def add_node(self, node_id: int, now: float, local: bool = False) -> NodeSchedule:
        """A node connected (ready for a session once it has loaded that session's scene); ``local``:
        from the coordinator's machine."""
        node = self.table.add(node_id, now)
        node.local = local
        for session in self.sessions.values():
            self._repartition(session, now, joined=node_id)
        return node

    def node_ready(self, node_id: int, now: float, share: int | None = None,
                   session_id: str = DEFAULT_SESSION) -> None:
        """The node loaded the session's scene (sort-last: its share of partition ``share``). A
        sort-first session whose newest state a published frame shows, or an interactive frame in
        flight will show, is not drawn again for it (at rest, a scan's session would draw its
        progressive still once more per node joining; a moving one, its frame twice); the node
        takes its tiles from the next frame owed."""
        node, session = self.nodes[node_id], self.sessions.get(session_id)
        if session is None:
            return
        if not node.ready:
            node.ready, node.idle_since = True, now
            self.table.touch(node, state_changed=True)
        session.ready.add(node_id)
        session.mode.share_loaded(node_id, share)
        self._load_next(session)
        if session.mode.needs_depth or not (session.demand.shown or session.interactive_in_flight):
            self._changed(session, now, supersede=False)
        else:   # the picture shown is the same with one more node: it draws from the next frame owed on
            self._advance(now)

    def levels_ready(self, node_id: int, session_id: str = DEFAULT_SESSION,
                     group_levels: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> None:
        """The node holds the levels of detail of the session's scene: its moving frames may use
        them; ``group_levels``: its groups' levels (errors, triangles, boxes), for the predictions."""
        session = self.sessions.get(session_id)
        if session is not None:
            session.levels.add(node_id)
            if group_levels is not None:
                session.set_group_levels(*group_levels)

    def set_speed(self, node_id: int, speed: float) -> None:
        """Calibrated relative speed (seed 003 §1; slowest = 1), the balancers' node weight."""
        self.nodes[node_id].speed = float(speed)

    def remove_node(self, node_id: int, now: float) -> None:
        """The node is gone: its owed tiles go to the others (or their frames are dropped when no
        ready node is left)."""
        node = self.table.remove(node_id)
        if node is None:
            return
        for session in list(self.sessions.values()):
            held = node_id in session.ready
            session.ready.discard(node_id)
            session.levels.discard(node_id)
            if node_id in session.loads_waiting:
                session.loads_waiting.remove(node_id)
            elif not held:   # it was loading the scene (or had failed to): the next node loads it
                self._load_next(session)
            if self._repartition(session, now):
                self._changed(session, now, supersede=False)
                continue
            ready = self.table.holding(session.ready)
            for job in list(session.frames.values()):
                owed = job.owed_by(node_id)
                if owed and not ready:
                    self._cancel(job, now)
                elif owed:
                    self._redispatch(job, owed, ready, now)
            if held:
                self._changed(session, now, supersede=False)
        self._advance(now)

    # ----------------------------------------------------------------- tile events
    def receive_tile(self, node_id: int, header: TileHeader, payload: bytes, now: float) -> FrameJob | None:
        """A node's tile message as it came: its rect inside its frame (before its payload is
        decoded: no decompression bombs), its bytes checked and decoded as the frame's mode says,
        then :meth:`tile_arrived`. ProtocolError when it is not a tile the node owes, or not readable."""
        job = self.in_flight.get(header.frame_id)
        session = self.sessions[job.session] if job is not None else self.default
        width, height = job.size if job is not None else (max(s.size[0] for s in self.sessions.values()),
                                                          max(s.size[1] for s in self.sessions.values()))
        if not (header.rect.x1 <= width and header.rect.y1 <= height):
            raise ProtocolError(f"tile rect {header.rect.as_list()} lies outside the {width}x{height} frame")
        return self.tile_arrived(node_id, header, payload, now, session.mode.read_tile(job, header, payload))

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
            self.table.check_owed(node, key, "tile")
            self.table.answered(node, key, now)
            self._advance(now)
            return None
        tile = job.accept(node_id, header, payload, depth_tile)
        self.table.answered(node, key, now, job.busy_ms(header.tile_id, header))
        if tile is None:
            self._advance(now)
            return None
        node.tiles_rendered += 1
        node.failures = 0
        if job.one_by_one and job.pull_queue and node_id in self.sessions[job.session].ready:
            self._push(job, node, job.pull_next(), now)   # behind the tiles queued there meanwhile
        if job.complete:
            self._complete(job, now)
        self._advance(now)
        return job

    def tile_sent(self, node_id: int, frame_id: int, tile_id: int, send_ms: float,
                  counters: dict[str, float | str] | None = None) -> None:
        """A node's ``tile_sent``: how long the tile took to send, and its per-tile counters."""
        job = self.in_flight.get(frame_id)
        if job is None:
            job = next((s.awaiting_send[frame_id] for s in self.sessions.values() if frame_id in s.awaiting_send),
                       None)
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
        self.table.check_owed(node, key, "render_error for tile")
        node.state_sent = None   # the failure may be a state it could not apply: send it whole
        if key not in node.outstanding:
            return
        self.table.answered(node, key, now)
        job = self.in_flight.get(frame_id)
        part = job.tiles[tile_id].part_of if job is not None and 0 <= tile_id < len(job.tiles) else None
        drawing = None if part is None else (frame_id, part)
        if drawing is None or drawing != node.failed_drawing:   # a wall tile's pieces fail as one drawing
            node.failures += 1
        node.failed_drawing = drawing
        if node.failures >= self.config.max_tile_failures:
            self._actions.append(CloseNode(node_id, 1011, f"{node.failures} tiles failed in a row"))
            self.remove_node(node_id, now)
            return
        if job is not None and not job.tiles[tile_id].done and job.tiles[tile_id].node_id == node_id:
            session = self.sessions[job.session]
            movable = session.mode.tiles_move
            others = [n for n in self.table.holding(session.ready) if n is not node and movable] or [node]
            self._redispatch(job, [tile_id], others, now)
        self._advance(now)

    def tiles_skipped(self, node_id: int, frame_id: int, tile_ids: Iterable[int]) -> None:
        """The node skipped these queued tiles of a frame it was told was dropped (its
        ``tiles_dropped``); ProtocolError for a tile that was not dropped while it owed it."""
        node = self.nodes.get(node_id)
        if node is not None:
            self.table.skipped(node, frame_id, tile_ids)

    def still_converged(self, now: float, version: int, session_id: str = DEFAULT_SESSION) -> None:
        """The coordinator found the session's still of ``version`` converged: no more samples are
        owed, and those in flight (started before it knew) are dropped."""
        session = self.sessions.get(session_id)
        if session is not None and session.demand.still_converged(version):
            for job in [job for job in session.frames.values() if job.still]:
                self._cancel(job, now)
            self._advance(now)

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

    def viewer_tiles(self, job: FrameJob) -> list[ViewerTile]:
        """What viewers get of complete frame ``job`` (its session's mode assembles it: tiles as
        sent, or a depth frame merged), each piece with the slot of the node that drew it."""
        slots = {n.node_id: n.slot for n in self.nodes.values()}
        return self.sessions[job.session].mode.viewer_tiles(job, lambda node_id: slots.get(node_id or 0,
                                                                                              NO_NODE_SLOT))

    # ----------------------------------------------------------------- internals
    def _back_up_stragglers(self, now: float) -> None:
        """Copy the tiles of overdue nodes to others that hold their scene (see the module
        docstring); not where tiles cannot move (sort-last: no other node holds the share)."""
        for node in self.table.overdue(self.in_flight, self.config.backup_factor, self.config.backup_floor_s, now):
            owed = [(self.in_flight[f], t) for f, t in node.outstanding if f in self.in_flight]
            movable = [(job, t) for job, t in owed if self.sessions[job.session].mode.tiles_move]
            holders = [self.table.holding(self.sessions[job.session].ready) for job, _ in movable]
            if not any(n is not node for ready in holders for n in ready):
                continue
            node.suspect = True
            self.table.touch(node, state_changed=True)
            self.backups += 1
            for job, tile_id in movable:
                others = [n for n in self.table.holding(self.sessions[job.session].ready) if n is not node]
                if not others or job.tiles[tile_id].done or job.tiles[tile_id].node_id != node.node_id:
                    continue
                job.tiles[tile_id].earlier.add(node.node_id)
                self._redispatch(job, [tile_id], others, now, pull=False)

    def _redispatch(self, job: FrameJob, tile_ids: list[int], candidates: list[NodeSchedule], now: float,
                    pull: bool | None = None) -> None:
        """Tiles of ``job`` to draw again: back at the head of its pull queue (a pull frame, unless
        ``pull`` says otherwise), else each to the candidate that owes least."""
        if job.pull if pull is None else pull:
            for tile_id in reversed(tile_ids):
                job.tiles[tile_id].node_id = None
                job.pull_queue.appendleft(tile_id)
            return
        for tile_id in tile_ids:
            self._push(job, min(candidates, key=lambda n: (len(n.outstanding), n.node_id)), [tile_id], now)

    def _changed(self, session: SessionFrames, now: float, supersede: bool) -> int:
        """Something of ``session`` changed that needs a new frame; returns the first frame id
        that can show it."""
        first = self.next_frame_id
        session.demand.changed(now)
        if supersede:
            for job in list(session.frames.values()):
                if job.still or not self._begun(job):
                    self._cancel(job, now)
        self._advance(now)
        return first

    def _begun(self, job: FrameJob) -> bool:
        """True once a node works on ``job``: a tile arrived, a pulled tile went out, one of its
        tiles heads a node's queue, or it was dispatched ahead (else a session whose inputs come
        faster than a node's tile would have its frame dropped and queued again, never begun)."""
        return bool(job.tiles_done or job.ahead or (job.pull and len(job.pull_queue) < len(job.tiles))
                    or self.table.heads(job.frame_id))

    def _cancel(self, job: FrameJob, now: float) -> None:
        """Drop ``job``: nodes that owe tiles of it are told to skip those still queued (the next
        tile a node owes counts as begun now: lenient, the node may still finish the dropped one)."""
        del self.in_flight[job.frame_id]
        session = self.sessions.get(job.session)
        if session is not None:
            session.frames.pop(job.frame_id, None)
            session.frames_cancelled += 1
            if job.still:
                session.demand.still_dropped(job.version)
            self.fair.finished(job.session, session.charges.pop(job.frame_id, (0.0, 1.0))[0], None, now)
        self.frames_cancelled += 1
        for node in self.nodes.values():
            if self.table.drop(node, job.frame_id, now):
                self._actions.append(CancelFrames(node.node_id, (job.frame_id,)))

    def _advance(self, now: float) -> None:
        """Hand out pulled tiles, then start every frame that is owed and allowed, the session
        that has had least node time first."""
        self._pump_pull(now)
        while free := self._wanting_work(now):
            wanting = [s for s in self.sessions.values() if s.may_start(now, self._free_for(s, free))]
            if len(wanting) > 1 or (wanting and len(self.sessions) > 1):
                busy = [s.id for s in self.sessions.values() if s.frames]
                order = self.fair.order([s.id for s in wanting], busy, now)
                wanting = [self.sessions[order[0]]] if order else []   # none: the least served goes next
            if not wanting:
                return
            session = wanting[0]
            kind = session.owed(now)
            assert kind is not None
            self._start_frame(session, now, still=kind == STILL)
            self._pump_pull(now)

    @staticmethod
    def _goes_ahead(session: SessionFrames) -> bool:
        """A frame of ``session`` may go to a node ending its last tile: it has no interactive frame
        in flight (its next frame would otherwise bind its camera a whole frame early: latency over
        two of its frame intervals, measured on the virtual clock; a progressive still's next sample
        may, the camera rests) and does not rotate tiles (they go to the first node freed; pulled
        ahead, a heavy tile could go to a slow node)."""
        last = session.mode.tiles.last
        return all(job.still for job in session.frames.values()) and not (last is not None and last.pull)

    def _wanting_work(self, now: float) -> set[int]:
        """The nodes that want work: the idle ones, and those ending their last tile when some
        session may go ahead (per event, so the nodes are looked at only then)."""
        if any(self._goes_ahead(s) for s in self.sessions.values()):
            return self.table.wanting_work(self.in_flight, now)
        return self.table.idle

    def _free_for(self, session: SessionFrames, free: set[int]) -> set[int]:
        """The nodes of ``free`` (:meth:`_wanting_work`) a frame of ``session`` may start on. While
        only some nodes hold its scene (the others still loading it) and none of those is free but
        another node is, its holders stand in: its frame may start and its tiles queue at them, as
        other sessions' tiles queue at busy nodes. Else the others' frames, started whenever one of
        their nodes frees up, keep its holders' queues from ever running dry, and it never starts
        (measured: a session of the 990k scan that one node held waited 14 s for its first frame,
        until a second node held it)."""
        nodes = free if self._goes_ahead(session) else self.table.idle
        if nodes and session.ready.isdisjoint(nodes):
            return {n.node_id for n in self.table.holding(session.ready)}
        return nodes

    def _scarcity(self, session: SessionFrames) -> float:
        """The ready nodes over those of them that hold ``session``'s scene (1 when all do): how
        much its node time counts in its fair share (:class:`FairShare`)."""
        ready = [n for n in self.nodes.values() if n.ready]
        holders = sum(n.node_id in session.ready for n in ready)
        return len(ready) / holders if holders else 1.0

    def _pieces(self, session: SessionFrames, holders: int, scarcity: float, now: float) -> int:
        """How many pieces a frame of ``session`` is cut into (1: none). While only some nodes
        hold its scene (``scarcity`` > 1) and another session had work within the last half
        second (:meth:`FairShare.others_active`; whether one has a frame in flight at this instant
        says little: a moving session has none between its frames), a sort-first
        frame whose last one took each of its ``holders`` more than :data:`PIECE_MS` goes to them
        in pieces of about that, one at a time: every other session's tiles at those nodes then
        wait for one piece, not a whole frame (the 990k scan's still samples took 120-250 ms on the
        one node holding it). Its first frame, not measured yet, goes in :data:`FIRST_FRAME_PIECES`."""
        if (scarcity <= 1.0 or session.mode.needs_depth or not session.mode.tiles_move or session.wall is not None
                or not self.fair.others_active(session.id, now)):
            return 1
        if (cost := self.fair.frame_cost(session.id)) is None:
            return FIRST_FRAME_PIECES
        return min(MAX_PIECES, max(1, math.ceil(cost / (holders * PIECE_MS))))

    def _start_frame(self, session: SessionFrames, now: float, still: bool) -> None:
        ready = self.table.holding(session.ready)
        width, height = session.size
        raw = ((session.demand.still_plan.most > 1 if still else session.video_only and full_analysis(session.size))
               and all(n.local for n in ready) and width * height <= self.config.size[0] * self.config.size[1])
        scarcity = self._scarcity(session)
        job, error = session.start_frame(self.next_frame_id, ready, now, still, raw_tiles=raw,
                                         pieces=self._pieces(session, len(ready), scarcity, now))
        if error is not None:
            self._actions.append(BalancerFailed(error))
        self.next_frame_id += 1
        self.in_flight[job.frame_id] = job
        session.charges[job.frame_id] = (self.fair.started(session.id, scarcity), scarcity)
        job.ahead = self.table.idle.isdisjoint(session.ready)   # started for a node ending its last tile
        if job.one_by_one:
            for node in sorted(ready, key=lambda n: (-n.speed, n.node_id)):
                if job.pull_queue:
                    self._push(job, node, job.pull_next(), now)
        elif not job.pull:
            by_node: dict[int, list[int]] = {}
            for tile in job.tiles:
                assert tile.node_id is not None
                by_node.setdefault(tile.node_id, []).append(tile.tile_id)
            for node_id, tile_ids in by_node.items():
                self._push(job, self.nodes[node_id], tile_ids, now)

    def _repartition(self, session: SessionFrames, now: float, joined: int | None = None,
                     force: bool = False) -> bool:
        """The node set changed (``joined``: a node that just connected; ``force``: the session is
        new). True when the session's mode makes a new data partition of it (sort-last): its frames
        in flight are dropped and every node is told its share. Otherwise the joined node (every
        node, with ``force``) is told to load the session's scene."""
        loads = session.mode.nodes_changed({n.node_id: n.speed for n in self.nodes.values()})
        if loads is None:
            if force:   # one node after the other: the others keep serving the sessions on screen
                session.loads_waiting = sorted(self.nodes, key=lambda i: (-self.nodes[i].speed, i))
                self._load_next(session)
            elif joined is not None:
                self._actions.append(LoadScene(joined, None, session.scene_key))
            return False
        for job in list(session.frames.values()):
            self._cancel(job, now)
        self._actions.extend(LoadScene(node_id, share, session.scene_key) for node_id, share in loads.items())
        return True

    def _load_next(self, session: SessionFrames) -> None:
        """Tell the next node of ``session.loads_waiting`` to load the session's scene. A new
        session's scene is loaded by one node at a time (:meth:`add_session`): a large scene's parse
        and upload then hold up one node's tiles of the other sessions, not every node's at once, and
        its first node is ready sooner than when all parse it side by side on shared cores."""
        if session.loads_waiting:
            self._actions.append(LoadScene(session.loads_waiting.pop(0), None, session.scene_key))

    def scene_failed(self, node_id: int, session_id: str) -> None:
        """The node could not load the session's scene: the next node waiting tries."""
        session = self.sessions.get(session_id)
        if session is not None:
            self._load_next(session)

    def _push(self, job: FrameJob, node: NodeSchedule, tile_ids: list[int], now: float) -> None:
        for tile_id in tile_ids:
            job.tiles[tile_id].node_id = node.node_id
        self.table.assign(node, [(job.frame_id, tile_id) for tile_id in tile_ids], now)
        state = self.sessions[job.session].state_for(node, job)
        self._actions.append(RenderTiles(node.node_id, job.render_message(tile_ids, state)))

    def _pump_pull(self, now: float) -> None:
        """Tile rotation (seed 000 §4.3): idle nodes pull the next tiles (heaviest first), oldest frame
        first; when several are idle at once the fastest gets the heaviest, then the first freed.
        A node pulls only tiles of sessions whose scene it holds."""
        if not self.table.idle or not any(job.pull_queue for job in self.in_flight.values()):
            return
        idle = sorted((self.nodes[i] for i in self.table.idle), key=lambda n: (-n.speed, n.idle_since, n.node_id))
        for job in self.in_flight.values():
            holders = self.sessions[job.session].ready
            while job.pull_queue and idle:
                node = idle[0] if idle[0].node_id in holders else next((n for n in idle if n.node_id in holders), None)
                if node is None:
                    break
                idle.remove(node)
                self._push(job, node, job.pull_next(), now)

    def _complete(self, job: FrameJob, now: float) -> None:
        session = self.sessions[job.session]
        del self.in_flight[job.frame_id]
        del session.frames[job.frame_id]
        for older in [j for j in session.frames.values() if j.frame_id < job.frame_id]:
            self._cancel(older, now)
        self.last_published_id = job.frame_id
        first_answer = session.demand.published(job.version)
        session.stats.record_publish(now, now - job.changed_at if first_answer and not job.still else None)
        self._actions.append(PublishFrame(job))
        session.awaiting_send[job.frame_id] = job
        for old in [k for k in session.awaiting_send if k < job.frame_id - AWAITING_SEND_FRAMES]:
            del session.awaiting_send[old]
        timings = job.timings()
        charge, scarcity = session.charges.pop(job.frame_id, (0.0, 1.0))
        self.fair.finished(session.id, charge, sum(t.busy_ms for t in timings), now, scarcity)
        if not (job.still or job.one_by_one):   # the balancer learns from its own partitions
            session.mode.take_timings(job.frame_id, timings)
        for node_id, rate in job.ms_per_px_by_node().items():
            if node_id in self.nodes:
                self.nodes[node_id].ms_per_px = rate
        self._take_timings(job)

    def _take_timings(self, job: FrameJob) -> None:
        """Roll a complete frame's phases up per node once every tile's send time is in; an
        interactive frame's timings also go to the balancer and the imbalance figures."""
        session = self.sessions.get(job.session)
        if session is None or not job.timings_complete or session.awaiting_send.pop(job.frame_id, None) is None:
            return
        timings = job.timings()
        rollup = job.rollup_by_node(timings)
        for node_id, (phases, rects, readback, counters) in rollup.items():
            node = self.nodes.get(node_id)
            if node is not None:
                node.last_phases, node.last_tiles, node.last_readback, node.counters = phases, rects, readback, counters
        busy_ms = {n: sum(r[0].values()) for n, r in rollup.items()}
        if not job.still:
            session.lod.frame_done(max(busy_ms.values(), default=0.0) / 1e3)
        if not (job.still or job.one_by_one) and session.mode.take_timings(job.frame_id, timings):
            session.stats.record_balance(busy_ms)
