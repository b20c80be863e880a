"""The coordinator's frame scheduler without I/O (seed 004's APP stage; the sans-I/O pattern of
websockets' ``Protocol``): events in, actions out, clock readings passed in. The asyncio service and
the virtual-clock benchmarks drive this same object. docs/explanation/scheduler.md tells what it does
and why; in short:

Events: the camera or the scene state changed, a balancer was chosen, a node joined / became
ready / left, a tile arrived, a tile's send time arrived, a tick. Actions (:meth:`drain`): send a
render message, cancel frames on a node, publish a frame, close a node.

* **Render on demand.** A frame starts only when something changed since the newest frame, while
  the balancer settles (at most ``settle_frames`` more, while the partition still moves), or for the
  still once nothing changed for ``still_delay_ms``: its jittered samples in ``still_codec``
  (:mod:`tessera.scheduling.refinement`), each sent ahead to nodes ending their tile of the one before.
* **Late camera and scene state binding** (seed 000 §4.5, seed 004). A frame takes the newest camera
  and scene state (:class:`tessera.scene.timeline.SceneTimeline`, one version of the state log,
  sent to each node as a delta on the version it has) when it starts, and it starts only when a node
  wants work: idle, or its last tile ends within its round trip (:mod:`tessera.scheduling.node_table`).
  At most ``max_in_flight`` frames are in flight; a change drops the still and frames no node began.
* **Never torn, never backwards.** A frame is published only when every tile of its one camera and
  one scene state arrived; publishing it drops every older frame in flight.
* **Push and pull dispatch.** Push partitions go to their nodes at once; pull partitions (tile
  rotation, seed 000 §4.3) hand one tile at a time to an idle node, heaviest first, oldest frame
  first, fastest node first. A node that leaves has its owed tiles re-dispatched.
* **Stragglers and failed tiles.** A node ``backup_factor`` times later than its expected time for
  its tile (at least ``backup_floor_s``) has its tiles copied to other nodes, the first copy back
  winning; a failed tile goes to another node; ``max_tile_failures`` in a row, or owing a tile
  longer than ``tile_timeout_s`` and three times its longest recent tile, close the node.
* **Decomposition modes.** One :class:`tessera.decomposition.mode.DecompositionMode` (``--mode``)
  says what a frame is cut into, what the nodes are asked and must load, and whether tiles may move.
* **Sessions.** Every frame belongs to a :class:`SessionFrames`; sessions share the nodes, the least
  served first (:class:`FairShare`; a scene held by only some nodes: :meth:`FrameScheduler._free_for`,
  :meth:`FrameScheduler._scarcity`, :meth:`FrameScheduler._pieces`). Methods that act on one session
  take its id and default to :data:`DEFAULT_SESSION`.
* **Timing roll-up.** Each complete frame's per-node phases feed the stats, and an interactive
  frame's the balancer as soon as it completes; send times are added when they arrive.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Collection, Hashable, Iterable, Mapping

import numpy as np

from tessera.balancers.base import Balancer
from tessera.decomposition.mode import ViewerTile
from tessera.geometry import Camera, Rect
from tessera.scene.state import ObjectPatch
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.actions import (
    Action,
    CloseNode,
)
from tessera.scheduling.config import SchedulerConfig
from tessera.scheduling.dispatch import STRAGGLER_CHECK_S, FrameDispatch
from tessera.scheduling.fair_share import FairShare
from tessera.scheduling.frame_jobs import DEFAULT_SESSION, FrameJob, check_late_tile
from tessera.scheduling.node_table import NodeSchedule, NodeTable
from tessera.scheduling.render_demand import STILL
from tessera.scheduling.session_frames import SessionFrames
from tessera.wire.codec import Codec
from tessera.wire.depth_tiles import DecodedDepthTile
from tessera.wire.protocol import NO_NODE_SLOT, ProtocolError, TileHeader


class FrameScheduler(FrameDispatch):
    """Frames in flight for one coordinator; see the module docstring. Every event takes ``now``
    (seconds on any monotonic clock) and may queue actions; :meth:`drain` returns them in order.
    ``config``, ``balancer`` and ``scene`` (the spec nodes load; None: whatever the adapter's own
    scene is) make the default session; sessions share ``config``'s timeouts."""

    def __init__(self, config: SchedulerConfig, balancer: Balancer, scene: str | None = None) -> None:
        self.config = config
        self.sessions: dict[str, SessionFrames] = {}
        self.fair = FairShare()
        self.in_flight: dict[int, FrameJob] = {}
        self.retired: OrderedDict[int, tuple[Codec, list[Rect]]] = OrderedDict()
        self.next_frame_id = 1
        self.last_published_id = 0
        self.frames_cancelled = 0
        self.table = NodeTable()
        self.nodes = self.table.nodes
        self._actions: list[Action] = []
        self._next_straggler_check = 0.0
        self._expected = None
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
        held = self._stills_held()
        if len(self.sessions) == 1:   # one session is always in turn
            times = [at] if (at := self.default.start_due(now, self._free_for(self.default, free))) is not None else []
        else:
            backlogged = [s.id for s in self.sessions.values() if s.frames or s.owed(now) is not None]
            times = [at for s in self.sessions.values()
                     if (at := s.start_due(now, self._free_for(s, free))) is not None
                     and self.fair.in_turn(s.id, backlogged)
                     and not (held and s.owed(now, ignore_quiet=True) == STILL)]
        if self._expected is not None:
            times.append(self._expected[1])
        if self.in_flight:
            times.append(min(self.table.timeout_at(self.config.tile_timeout_s) or math.inf,
                             self._next_straggler_check))
            if any(self._goes_ahead(s) for s in self.sessions.values()) and (
                    at := self.table.next_wanting_at(self.in_flight, now)) is not None:
                times.append(at)
        return min(times) if times else None

    def expect_nodes(self, count: int, until: float) -> None:
        """``count`` nodes are on their way (the coordinator's local nodes): sessions whose nodes
        each hold a share of the scene (sort-last) are partitioned once that many joined, or at
        ``until`` (s), not once per node as they join (the first would load the whole scene as
        a share of one, then a half, ...)."""
        self._expected = (count, until) if count > len(self.nodes) else None

    # ----------------------------------------------------------------- sessions
    def add_session(self, session_id: str, config: SchedulerConfig, balancer: Balancer, scene_key: str | None,
                    now: float, weight: float = 1.0, held: Collection[int] = ()) -> SessionFrames:
        """A new session of ``config``'s size, mode and codecs, whose nodes load ``scene_key``
        (None: the coordinator's scene); every node connected is told to load it, but those
        ``held`` names (they hold it already: :meth:`nodes_ready` follows)."""
        if session_id in self.sessions:
            raise ValueError(f"session {session_id!r} exists already")
        session = self.sessions[session_id] = SessionFrames(session_id, config, balancer, scene_key)
        self.fair.add(session_id, weight)
        if self.nodes:
            self._repartition(session, now, force=True, held=held)
        return session

    def load_now(self, session_id: str) -> None:
        """Tell every node still waiting to load the session's scene to load it now, side by side
        (a mesh sent as arrays, issue 33: read from memory in milliseconds, not parsed from a file)."""
        session = self.sessions.get(session_id)
        if session is not None:
            for node_id in list(session.loads_waiting):
                self._start_load(session, node_id)

    def rest(self, session_id: str) -> None:
        """The session's state is drawn once more at most (a frame owed or in flight), with no
        settle frames and no still: a new scene is on its way (issue 33: a mesh loaded ahead), and
        other sessions' still samples wait for it (:attr:`SessionFrames.goes_first`)."""
        session = self.sessions.get(session_id)
        if session is not None:
            session.demand.rest()
            session.scene_coming = True

    def remove_session(self, session_id: str, now: float) -> None:
        """The session is closed: its frames are dropped (nodes skip their tiles)."""
        if self._drop_session(session_id, now) is not None:
            self._advance(now)

    def replace_session(self, session_id: str, config: SchedulerConfig, balancer: Balancer, scene_key: str | None,
                        now: float, held: Collection[int] = (), keep_partition: bool = False) -> SessionFrames:
        """Session ``session_id`` shows ``scene_key`` from now on: :meth:`remove_session`, then
        :meth:`add_session`, no frame of another session started between them (its first frame goes
        first: :attr:`SessionFrames.awaits_first_frame`, while its nodes are not told yet to draw
        it). ``keep_partition``: the
        partition goes on from the old session's, with its balancer (issue 33: a simulation's next
        step is drawn much as the one before, so the balancer learns across steps instead of
        starting from an equal split each step); else ``balancer`` starts afresh."""
        old = self._drop_session(session_id, now)
        session = self.add_session(session_id, config, balancer, scene_key, now, held=held)
        session.replaced = True
        if keep_partition and old is not None and old.config.mode == config.mode and old.size == config.size:
            session.mode.tiles = old.mode.tiles
        return session

    def _drop_session(self, session_id: str, now: float) -> SessionFrames | None:
        """Drop the session and its frames (nodes skip their tiles); None: there was none."""
        session = self.sessions.pop(session_id, None)
        if session is not None:
            for job in list(session.frames.values()):
                self._cancel(job, now)
            self.fair.remove(session_id)
            self._load_waiting()   # the loads that waited for its first frame
        return session

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
    def add_node(self, node_id: int, now: float, local: bool = False, host: str = "") -> NodeSchedule:
        """A node connected (ready for a session once it has loaded that session's scene, told after
        the node of its ``host`` loading it, if one is; the coordinator's own session's last);
        ``local``: from the coordinator's machine."""
        node = self.table.add(node_id, now)
        node.local, node.host = local, host
        # The sessions opened for a scene first, the coordinator's own last: a node reads and uploads
        # its scenes in the order it is told them.
        for session in sorted(self.sessions.values(), key=lambda s: s.id == DEFAULT_SESSION):
            self._repartition(session, now, joined=node_id)
        return node

    def node_holds(self, node_id: int, triangles: int) -> None:
        """The largest scene (or share) a session shows on the node has ``triangles``: its tiles may
        take as long as that many triangles take (:meth:`NodeTable.allowed_s`)."""
        node = self.nodes.get(node_id)
        if node is not None:
            node.triangles = int(triangles)

    def node_ready(self, node_id: int, now: float, share: int | None = None,
                   session_id: str = DEFAULT_SESSION) -> None:
        """The node loaded the session's scene (sort-last: its share of partition ``share``). A
        sort-first session whose newest state a published frame shows, or an interactive frame in
        flight will show, is not drawn again for it (at rest, a scan's session would draw its
        progressive still once more per node joining; a moving one, its frame twice); the node
        takes its tiles from the next frame owed."""
        self.nodes_ready([node_id], now, share, session_id)

    def nodes_ready(self, node_ids: Collection[int], now: float, share: int | None = None,
                    session_id: str = DEFAULT_SESSION) -> None:
        """:meth:`node_ready` of several nodes at once (those gone are passed over): the next frame
        is split among them all."""
        session = self.sessions.get(session_id)
        if session is None:
            return
        for node in [self.nodes[i] for i in node_ids if i in self.nodes]:
            if not node.ready:
                node.ready, node.idle_since = True, now
                self.table.touch(node, state_changed=True)
            session.ready.add(node.node_id)
            session.loading.discard(node.node_id)
            session.mode.share_loaded(node.node_id, share)
        if session.mode.needs_depth or not (session.demand.shown or session.interactive_in_flight):
            self._changed(session, now, supersede=False)
        else:   # the picture shown is the same with one more node: it draws from the next frame owed on
            self._advance(now)
        self._load_waiting()   # once its frame started: a first frame drawn whole goes out first

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
            session.loading.discard(node_id)
            if node_id in session.loads_waiting:
                session.loads_waiting.remove(node_id)
            elif not held or not session.ready:   # it was loading the scene (or had failed to, or drew its
                self._load_next_free(session)       # first frame alone): the next loads it
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
            check_late_tile(header, self.retired.get(header.frame_id))
            self.table.answered(node, key, now)
            node.learn_pace(header)
            self._advance(now)
            return None
        tile = job.accept(node_id, header, payload, depth_tile)
        self.table.answered(node, key, now, job.busy_ms(header.tile_id, header))
        if tile is None:    # a copy that lost the race: the node was slower than expected, not idle
            node.learn_pace(header)
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
        """A node's ``tile_sent``: how long the tile took to send, and its per-tile counters (a
        point cloud's still sample that left points in view out says so: ``points_left_out``)."""
        job = self.in_flight.get(frame_id)
        if job is None:
            job = next((s.awaiting_send[frame_id] for s in self.sessions.values() if frame_id in s.awaiting_send),
                       None)
        if job is not None:
            job.record_send(node_id, tile_id, max(float(send_ms), 0.0), counters)
            session = self.sessions.get(job.session)
            if session is not None and job.still and (counters or {}).get("points_left_out"):
                session.demand.points_left_out(job.version)
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
        """Time passed: back up stragglers' tiles, drop nodes that owe a tile for longer than they
        are allowed (:meth:`NodeTable.allowed_s`), start what is due."""
        if now >= self._next_straggler_check:
            self._next_straggler_check = now + STRAGGLER_CHECK_S
            self._back_up_stragglers(now)
        if self._expected is not None and not self._joining(now):   # the wait ran out: partition those there
            for session in [s for s in self.sessions.values() if s.mode.shares_data]:
                if self._repartition(session, now):
                    self._changed(session, now, supersede=False)
        for node in self.table.timed_out(now, self.config.tile_timeout_s):
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

    def scene_failed(self, node_id: int, session_id: str) -> None:
        """The node could not load the session's scene: the next node waiting tries."""
        session = self.sessions.get(session_id)
        if session is not None:
            session.loading.discard(node_id)
            self._load_next(session)
            self._load_waiting()   # others' loads that waited for its first frame, when none will come
