"""The frame scheduler with render jobs (issue 35): posters and films drawn on the cluster beside
the sessions' frames, as fast as the nodes allow (:mod:`tessera.scheduling.render_jobs`).

:class:`JobScheduler` is the :class:`tessera.scheduling.scheduler.FrameScheduler` (events in,
actions out, the clock passed in) that also hands out render jobs' work:

* **Lower priority than the sessions' frames.** Each time the scheduler hands out work, the
  sessions' frames go first (the frame scheduler's own order: fair shares, render on demand);
  job tiles then go to the nodes still free. A job tile is one sample of one piece of a picture,
  about :data:`tessera.scheduling.render_jobs.PIECE_MS` of node time, so a session's next frame
  waits at most that behind one on a node. While no session has a frame in flight or owed, each
  node holds up to :data:`JOB_QUEUE` job tiles (the one it draws and the next, queued behind;
  sort-last: :data:`SHARES_JOB_QUEUE`), so
  it never idles between them whatever each one takes; otherwise job tiles go only to idle nodes,
  and those queued that no node has begun go back to their jobs (the session's frame then waits
  for one job tile per node at most).
* **A session's work like any other.** A job tile's node time counts as its session's in the fair
  shares (:meth:`tessera.scheduling.fair_share.FairShare.spent`): the session's own frames then
  wait for the others' as if it had drawn them. Of several jobs, the least served session's first,
  then the oldest.
* **Frames of one tile.** A job tile is a frame of its own (:class:`FrameJob` with ``job`` and
  ``item``), of its session's scene and of the state, clip and selection the job was made with,
  lossless (raw from the coordinator's machine, else PNG; the coordinator sizes pieces to fit a
  node's messages), in a still's sample's jitter. In sort-last (each node holds a share) it is
  a tile per share over the same piece, each drawn by the share's holder with depth, started when
  every holder has room for it, and merged by depth on the coordinator as a progressive still's
  sample is;
  a new data partition hands the session's job tiles in flight back to their jobs. A job tile is
  never the session's frame (it neither supersedes nor is superseded by them). A tile that fails
  or whose node lags goes to another node as any tile does (a lagging node's tile is expected to
  take what the same piece took in the picture before, and the job tiles queued behind it are
  handed back, not copied); one whose node leaves is handed back to its job and drawn again; a
  complete one is published (:class:`PublishFrame`) for the coordinator to accumulate.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Collection

from tessera.balancers.base import Partition, Tile
from tessera.scheduling.actions import CancelFrames, PublishFrame
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.node_table import NodeSchedule
from tessera.scheduling.render_jobs import CANCELLED, JobItem, RenderWork
from tessera.scheduling.scheduler import FrameScheduler
from tessera.scheduling.session_frames import SessionFrames
from tessera.wire.codec import Codec
from tessera.wire.protocol import ProtocolError, TileHeader

#: Dropped job tiles whose picture size is remembered (a node may still send the one it was on).
DROPPED_SIZES = 4096
#: Job tiles a node holds at most while no session draws: the one it draws and the next, queued
#: behind it (there when the node finishes the one before, however long either takes).
JOB_QUEUE = 2
#: The same in sort-last, where every holder draws each piece over its share: a share dear in one
#: piece and cheap in the next lets the other holders run this far ahead instead of waiting.
SHARES_JOB_QUEUE = 4


class JobScheduler(FrameScheduler):
    """A :class:`FrameScheduler` that also draws render jobs; see the module docstring. ``jobs``:
    the render jobs' work by job id, in the order they were added."""

    def __init__(self, *args, **kwargs) -> None:   # type: ignore[no-untyped-def]
        self.jobs: dict[str, RenderWork] = {}
        #: The picture size of dropped job tiles, by frame id, the newest :data:`DROPPED_SIZES`.
        self._dropped_sizes: OrderedDict[int, tuple[int, int]] = OrderedDict()
        super().__init__(*args, **kwargs)

    # ----------------------------------------------------------------- jobs
    def add_job(self, work: RenderWork, now: float) -> None:
        """Draw ``work``'s job from now on; KeyError for a session that does not exist, ValueError
        for a job id in use."""
        if work.spec.session not in self.sessions:
            raise KeyError(f"no session {work.spec.session!r}")
        if work.job_id in self.jobs:
            raise ValueError(f"job {work.job_id!r} exists already")
        self.jobs[work.job_id] = work
        self._advance(now)

    def end_job(self, job_id: str, now: float, state: str = CANCELLED, reason: str | None = None) -> None:
        """Job ``job_id`` is over (done, failed, cancelled): its tiles not back are dropped (nodes
        skip those still queued) and it hands out nothing more."""
        work = self.jobs.pop(job_id, None)
        if work is None:
            return
        if not work.finished:
            work.end(state, reason)
        for job in [job for job in self.in_flight.values() if job.job == job_id]:
            self._drop(job, now, hand_back=False)
        self._advance(now)

    def picture_taken(self, job_id: str, picture: int, now: float) -> None:
        """The coordinator holds picture ``picture`` of job ``job_id`` whole: later ones may start."""
        work = self.jobs.get(job_id)
        if work is not None:
            work.picture_finished(picture)
            self._advance(now)

    # ----------------------------------------------------------------- events that concern jobs
    def remove_session(self, session_id: str, now: float) -> None:
        """The session is gone: its jobs end too."""
        for job_id in [job_id for job_id, work in self.jobs.items() if work.spec.session == session_id]:
            self.end_job(job_id, now, reason="the session was closed or changed its scene")
        super().remove_session(session_id, now)

    def remove_node(self, node_id: int, now: float) -> None:
        """As the frame scheduler does; the job tiles the node owed go back to their jobs."""
        lost = [job for job in self.in_flight.values() if job.job is not None and job.owed_by(node_id)]
        super().remove_node(node_id, now)
        for job in lost:
            if job.frame_id in self.in_flight:
                self._drop(job, now, hand_back=True)
        self._advance(now)

    def _repartition(self, session: SessionFrames, now: float, joined: int | None = None,
                     force: bool = False, held: Collection[int] = ()) -> bool:
        """As the frame scheduler does; a new data partition (sort-last) drops the session's job
        tiles in flight (drawn from the old shares) and hands them back to their jobs."""
        changed = super()._repartition(session, now, joined, force, held)
        if changed:
            for job in [job for job in self.in_flight.values() if job.job is not None and job.session == session.id]:
                self._drop(job, now, hand_back=True)
        return changed

    def receive_tile(self, node_id: int, header: TileHeader, payload: bytes, now: float) -> FrameJob | None:
        """As the frame scheduler does; a tile of a dropped job tile is checked against its picture's
        size (larger than any session's frame) and then ignored."""
        size = self._dropped_sizes.get(header.frame_id)
        if size is None or header.frame_id in self.in_flight:
            return super().receive_tile(node_id, header, payload, now)
        if not (header.rect.x1 <= size[0] and header.rect.y1 <= size[1]):
            raise ProtocolError(f"tile rect {header.rect.as_list()} lies outside the {size[0]}x{size[1]} picture")
        return self.tile_arrived(node_id, header, payload, now)

    # ----------------------------------------------------------------- the frame scheduler's hooks
    def _advance(self, now: float) -> None:
        """The sessions' frames first (job tiles queued that no node has begun make way for them),
        then job tiles to the nodes with room."""
        if self.jobs and not self._quiet(now):
            self._make_way(now)
        super()._advance(now)
        if self.jobs:
            self._start_job_tiles(now, self._quiet(now))

    def _cancel(self, job: FrameJob, now: float) -> None:
        if job.job is None:
            super()._cancel(job, now)
        else:
            self._drop(job, now, hand_back=True)

    def _back_up(self, job: FrameJob, tile_id: int, node: NodeSchedule, others: list[NodeSchedule], now: float,
                 begun: bool) -> None:
        """As the frame scheduler does, but a job tile the lagging node has not begun goes back to
        its job (the node skips it, the nodes with room take it), not copied."""
        if job.job is None or begun:
            super()._back_up(job, tile_id, node, others, now, begun)
        else:
            self._drop(job, now, hand_back=True)

    def _complete(self, job: FrameJob, now: float) -> None:
        """A job tile is back: its node time is its session's, its node's rate is learnt, its item
        is drawn and the coordinator gets it; a frame of a session goes on as ever."""
        if job.job is None:
            super()._complete(job, now)
            return
        self._retire(job)
        busy_ms = sum(timing.busy_ms for timing in job.timings())
        self.fair.spent(job.session, busy_ms, now)
        for node_id, rate in job.ms_per_px_by_node().items():
            if node_id in self.nodes:
                self.nodes[node_id].ms_per_px = rate
        work = self.jobs.get(job.job)
        if work is not None and job.item is not None:
            work.drawn(job.item, busy_ms)
            self._actions.append(PublishFrame(job))

    # ----------------------------------------------------------------- internals
    def _quiet(self, now: float) -> bool:
        """No session has a frame in flight or owed: job tiles may go to nodes ending their last tile."""
        return not any(s.frames or s.owed(now, ignore_quiet=True) is not None for s in self.sessions.values())

    def _make_way(self, now: float) -> None:
        """A session draws: the job tiles in flight that head no node's queue (none has begun them)
        go back to their jobs, in order, and the nodes skip them."""
        queued = [job for job in self.in_flight.values() if job.job is not None and not self.table.heads(job.frame_id)]
        for job in sorted(queued, key=lambda j: j.frame_id):
            self._drop(job, now, hand_back=True)

    def _start_job_tiles(self, now: float, quiet: bool) -> None:
        """Job tiles to the nodes with room (:meth:`_may_draw`), the node holding fewest first, then
        the fastest."""
        waiting = [work for work in self.jobs.values() if work.waiting]
        full: set[int] = set()
        while waiting:
            open_nodes = [n for n in self.nodes.values() if n.schedulable and n.node_id not in full]
            if not open_nodes:
                return
            node = min(open_nodes, key=lambda n: (len(n.outstanding), -n.speed, n.node_id))
            holding = [work for work in waiting if self._may_draw(work, node, quiet)]
            item = None
            if holding:
                work = min(holding, key=lambda w: self.fair.served.get(w.spec.session, 0.0))   # then the oldest
                item = work.take()
            if item is None:
                full.add(node.node_id)
                continue
            self._start_job_tile(work, item, node, now)
            waiting = [work for work in waiting if work.waiting]

    def _may_draw(self, work: RenderWork, node: NodeSchedule, quiet: bool) -> bool:
        """``node`` may start a tile of ``work``: it holds its session's scene and has room (while
        ``quiet``, no session drawing, fewer than :data:`JOB_QUEUE` tiles owed, else none); in
        sort-last it holds a share and every holder has room (:data:`SHARES_JOB_QUEUE`): each draws the tile."""
        session = self.sessions[work.spec.session]
        shares = session.mode.job_nodes()
        depth = 1 if not quiet else JOB_QUEUE if shares is None else SHARES_JOB_QUEUE
        if shares is None:
            return node.node_id in session.ready and len(node.outstanding) < depth
        return (node.node_id in shares and session.ready.issuperset(shares)
                and all(self.nodes[i].schedulable and len(self.nodes[i].outstanding) < depth for i in shares))

    def _start_job_tile(self, work: RenderWork, item: JobItem, node: NodeSchedule, now: float) -> set[int]:
        """Start ``item`` on ``node`` (sort-last: on every share's holder, as a frame's depth tiles
        over the piece, merged on the coordinator as a still's sample is); returns the nodes it went to."""
        spec = work.spec
        rect, window = work.pieces[item.piece]
        mode = self.sessions[spec.session].mode
        shares = mode.job_nodes()
        drawers = [node] if shares is None else [self.nodes[node_id] for node_id in shares]
        # a sort-last tile is all depth (no core): its picture, merged, never leaves the coordinator
        codec = Codec.RAW if node.local or shares is not None else Codec.PNG
        partition = Partition(tuple(Tile(rect, drawer.node_id) for drawer in drawers))
        job = FrameJob.create(self.next_frame_id, spec.cameras[item.picture], spec.size, codec, 95, partition, now,
                              still=True, version=-1, state=spec.state, session=spec.session, scene=spec.scene,
                              depth=None if shares is None else mode.depth_request(partition), sample=item.sample,
                              plan=spec.plan, clip=spec.clip, highlight=spec.highlight)
        job.job, job.item, job.window = work.job_id, item, window
        job.expected_ms = work.piece_ms.get(item.piece) if shares is None else None
        self.next_frame_id += 1
        self.in_flight[job.frame_id] = job
        for index, drawer in enumerate(drawers):
            self._push(job, drawer, [index], now)
        return {drawer.node_id for drawer in drawers}

    def _drop(self, job: FrameJob, now: float, hand_back: bool) -> None:
        """Drop job tile ``job`` (nodes skip it if still queued); ``hand_back``: its item is drawn again."""
        if job.frame_id in self.in_flight:
            self._retire(job)
        self._dropped_sizes[job.frame_id] = job.size
        while len(self._dropped_sizes) > DROPPED_SIZES:
            self._dropped_sizes.popitem(last=False)
        for node in self.nodes.values():
            if self.table.drop(node, job.frame_id, now):
                self._actions.append(CancelFrames(node.node_id, (job.frame_id,)))
        work = self.jobs.get(job.job or "")
        if hand_back and work is not None and job.item is not None:
            work.hand_back(job.item)
