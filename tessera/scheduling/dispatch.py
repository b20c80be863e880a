"""How the frame scheduler (:mod:`tessera.scheduling.scheduler`) starts, dispatches, cancels and
completes frames: which session's frame starts when a node wants work, how it is cut while few
nodes hold its scene, pushed or pulled to the nodes, backed up when a node lags, and published
once whole. :class:`FrameDispatch` is the scheduler's state and these steps; the scheduler adds the
events that drive them. Pure: the clock comes in as ``now`` (s)."""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Collection

from tessera.geometry import Rect
from tessera.scheduling.actions import (
    Action,
    BalancerFailed,
    CancelFrames,
    LoadScene,
    PublishFrame,
    RenderTiles,
)
from tessera.scheduling.config import SchedulerConfig
from tessera.scheduling.fair_share import FairShare
from tessera.scheduling.frame_jobs import DEFAULT_SESSION, FrameJob
from tessera.scheduling.node_table import NodeSchedule, NodeTable
from tessera.scheduling.render_demand import STILL
from tessera.scheduling.session_frames import SessionFrames
from tessera.video.budget import full_analysis
from tessera.wire.codec import Codec

#: Frames that stay in the awaiting-send table after completing (their ``tile_sent`` may lag).
AWAITING_SEND_FRAMES = 8
#: Frames out of flight (published or dropped) whose tiles' rects and codec are remembered, so that
#: a late tile of one is still checked against what was asked.
RETIRED_MEMORY = 256
#: How often frames in flight are looked at for stragglers (s).
STRAGGLER_CHECK_S = 0.1
#: While few nodes hold a session's scene, its frames are cut into pieces expected to take about
#: this long (ms of node time) each on the nodes that hold it, at most :data:`MAX_PIECES`; its
#: first frame, whose cost is not known yet, into :data:`FIRST_FRAME_PIECES`.
PIECE_MS = 40.0
MAX_PIECES = 8
FIRST_FRAME_PIECES = 4
#: A session's first frame drawn whole holds the next node's load of its scene back only when a node
#: holding it holds this many triangles or more: a big scene's upload takes seconds of the cores the
#: frame is drawn on; a small one's is quick, and a node may want the next one at once (a tile it failed).
HOLD_LOADS_TRIANGLES = 1_000_000


class FrameDispatch:
    """The frame scheduler's state and its frame steps (see the module docstring); the events are
    :class:`tessera.scheduling.scheduler.FrameScheduler`'s."""

    config: SchedulerConfig
    sessions: dict[str, SessionFrames]
    fair: FairShare
    in_flight: dict[int, FrameJob]
    #: frame id → (its codec, each tile's rect) of the newest :data:`RETIRED_MEMORY` frames out of flight.
    retired: OrderedDict[int, tuple[Codec, list[Rect]]]
    next_frame_id: int
    last_published_id: int
    frames_cancelled: int
    table: NodeTable
    nodes: dict[int, NodeSchedule]
    backups: int
    _actions: list[Action]
    _next_straggler_check: float
    #: Nodes expected to join (their count) and until when they are waited for (s); None: none.
    _expected: tuple[int, float] | None
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
            node.backups += 1
            head = next(iter(node.outstanding))
            for job, tile_id in movable:
                # not to a node that still owes the tile (an earlier owner trusted again): it would
                # draw it twice, and its second answer is one it no longer owes
                others = [n for n in self.table.holding(self.sessions[job.session].ready)
                          if n is not node and (job.frame_id, tile_id) not in n.outstanding]
                if not others or job.tiles[tile_id].done or job.tiles[tile_id].node_id != node.node_id:
                    continue
                self._back_up(job, tile_id, node, others, now, begun=(job.frame_id, tile_id) == head)

    def _back_up(self, job: FrameJob, tile_id: int, node: NodeSchedule, others: list[NodeSchedule], now: float,
                 begun: bool) -> None:
        """Tile ``tile_id`` of ``job``, owed by overdue ``node`` (``begun``: the one it is on), goes
        to one of ``others`` too: the first copy back wins."""
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
        self._retire(job)
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
            if self._stills_held():
                wanting = [s for s in wanting if s.owed(now) != STILL]
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

    def _stills_held(self) -> bool:
        """A session awaits its first frame, or its next mesh step's (:attr:`SessionFrames.goes_first`):
        no still sample of another starts meanwhile (measured: the coordinator's own scene's 64
        samples, nobody watching, drew on the node's one GL thread while it uploaded a new session's
        scene, then between the pieces of its first frame; and between a simulation's steps, a
        sample before each step's frame, 0.3 s a step instead of 0.15)."""
        return any(s.goes_first for s in self.sessions.values())

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
                     force: bool = False, held: Collection[int] = ()) -> bool:
        """The node set changed (``joined``: a node that just connected; ``force``: the session is
        new). True when the session's mode makes a new data partition of it (sort-last): its frames
        in flight are dropped and every node is told its share. Otherwise the joined node (every
        node but those ``held`` names, with ``force``) is told to load the session's scene."""
        if session.mode.shares_data and self._joining(now):
            return False   # shares cut now would be cut again as each expected node joins
        loads = session.mode.nodes_changed({n.node_id: n.speed for n in self.nodes.values()})
        if loads is None:
            if force:   # one node after the other: the others keep serving the sessions on screen
                session.loads_waiting = sorted((i for i in self.nodes if i not in held),
                                               key=lambda i: (-self.nodes[i].speed, i))
                self._load_next(session)
            elif joined is not None:   # after the node loading it, if one is: it gets the cores first
                session.loads_waiting.append(joined)
                self._load_next_free(session)
            return False
        for job in list(session.frames.values()):
            self._cancel(job, now)
        self._actions.extend(LoadScene(node_id, share, session.scene_key) for node_id, share in loads.items())
        return True

    def _joining(self, now: float) -> bool:
        """Nodes are still expected to join (:meth:`FrameScheduler.expect_nodes`): fewer than
        expected have, and the wait has not run out. Once not, never again."""
        if self._expected is not None and (len(self.nodes) >= self._expected[0] or now >= self._expected[1]):
            self._expected = None
        return self._expected is not None

    def _start_load(self, session: SessionFrames, node_id: int) -> None:
        """Tell waiting node ``node_id`` to load the session's scene."""
        session.loads_waiting.remove(node_id)
        session.loading.add(node_id)
        self._actions.append(LoadScene(node_id, None, session.scene_key))

    def _load_next(self, session: SessionFrames, held_hosts: Collection[str] = ()) -> None:
        """Tell the first node of ``session.loads_waiting`` on each machine (:attr:`NodeSchedule.host`)
        where no node loads the session's scene now, and not one of ``held_hosts``, to load it. A
        new session's scene is loaded by one node of a machine at a time (:meth:`add_session`): a
        large scene's parse and upload then hold up one node's tiles of the other sessions, not
        every node's at once, and its first node is ready sooner than when all parse it side by
        side on shared cores. So are nodes that join while one loads it (local nodes started with
        the coordinator: after a restart the first of them draws the session's first frame while
        the others wait). Nodes on other machines share no cores with it: they load at once."""
        busy = {self.nodes[i].host for i in session.loading if i in self.nodes} | set(held_hosts)
        for node_id in list(session.loads_waiting):
            host = self.nodes[node_id].host if node_id in self.nodes else ""
            if host not in busy:
                busy.add(host)
                self._start_load(session, node_id)

    def _load_next_free(self, session: SessionFrames) -> None:
        """:meth:`_load_next`, but a machine where a node holding the session's scene (a big scene:
        :data:`HOLD_LOADS_TRIANGLES`) draws its first frame whole loads no more of it, nor (the
        coordinator's own session) does any while another session awaits its first frame: those
        loads wait until that frame is out (on shared cores a second node's upload of the scene, or
        every node's read of the coordinator's built-in scene, took the first node's cores while it
        loaded and drew a 24.8M-triangle model). A first frame cut into pieces (:meth:`_pieces`:
        other sessions keep the nodes busy) is shared by the next node once it holds the scene: that
        node loads at once."""
        if session.id == DEFAULT_SESSION and any(   # (not a scene switch, a simulation's next step: no starving)
                other is not session and other.awaits_first_frame and not other.replaced
                for other in self.sessions.values()):
            return
        held: set[str] = set()
        if (session.ready and session.camera is not None and not session.demand.published_any
                and not session.pieces_in_flight):
            held = {self.nodes[i].host for i in session.ready
                    if i in self.nodes and self.nodes[i].triangles >= HOLD_LOADS_TRIANGLES}
        self._load_next(session, held)

    def _load_waiting(self) -> None:
        """:meth:`_load_next_free` of every session (a first frame went out, or will not come)."""
        for session in list(self.sessions.values()):
            self._load_next_free(session)

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

    def _retire(self, job: FrameJob) -> None:
        """Take ``job`` out of flight, remembering what its tiles asked for."""
        del self.in_flight[job.frame_id]
        self.retired[job.frame_id] = (job.codec, [tile.rect for tile in job.tiles])
        while len(self.retired) > RETIRED_MEMORY:
            self.retired.popitem(last=False)

    def _complete(self, job: FrameJob, now: float) -> None:
        session = self.sessions[job.session]
        self._retire(job)
        del session.frames[job.frame_id]
        for older in [j for j in session.frames.values() if j.frame_id < job.frame_id]:
            self._cancel(older, now)
        self.last_published_id = job.frame_id
        first_answer = session.demand.published(job.version)
        self._load_waiting()
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
        for node_id, node in self.nodes.items():
            if node_id in rollup:
                phases, rects, readback, counters = rollup[node_id]
                node.last_phases, node.last_tiles, node.last_readback, node.counters = phases, rects, readback, counters
            else:   # no part in the latest frame: its tiles are not this frame's
                node.last_tiles, node.last_readback = [], []
        busy_ms = {n: sum(r[0].values()) for n, r in rollup.items()}
        if not job.still:
            slowest_s = max(busy_ms.values(), default=0.0) / 1e3
            session.lod.frame_done(slowest_s)
            if session.point_bounds is not None:
                session.points.frame_done(slowest_s)
        if not (job.still or job.one_by_one) and session.mode.take_timings(job.frame_id, timings):
            session.stats.record_balance(busy_ms)
