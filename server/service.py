"""The coordinator's asyncio adapter around :class:`tessera.scheduling.scheduler.FrameScheduler`: it turns
socket messages and the clock into scheduler events and carries out the scheduler's actions
(send render / cancel messages, publish frames to the store and the viewers, close nodes).

The decomposition mode (:mod:`tessera.decomposition`) lives in the scheduler: it reads each tile
(a depth tile is decoded and checked when it arrives) and assembles each complete frame for the
viewers (a depth frame merged on the coordinator: at 1080p with 4 nodes the merge costs 5–15 ms of
one core, below a node's render time, docs/benchmarks/compose.md); this module carries bytes.

What happens when — render on demand, late camera binding, superseded frames, publish order —
is decided in the scheduler; this module adds what needs I/O: the nodes' connections and scene
state, calibration (seed 003 §1), the viewers, the frame store, the CPU accounting and the
Prometheus histograms (:mod:`server.metrics`: each publish, each tile's node phases).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import time
from collections.abc import Iterable, Mapping
from concurrent.futures import Executor, Future, ThreadPoolExecutor

import numpy as np

from server.frame_store import FrameStore, PublishedFrame
from server.local_nodes import LOCAL_NODES_JOIN_S
from server.mesh_updates import MeshUpdates
from server.metrics import CoordinatorMetrics, ObservedFrameStats
from server.node_calibration import NodeCalibration
from server.nodes import NodeLink
from server.picking import PickDesk
from server.render_jobs import RenderJobs
from server.scene_adoption import adopt_scene
from server.scene_library import SceneLibrary
from server.service_report import ServiceReport
from server.session_persistence import SessionPersistence
from server.session_store import SessionStore
from server.sessions import Session, new_key
from server.settings import Settings
from server.still_refinement import Refined
from server.viewers import ViewerHub
from tessera.balancers import create_balancer
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import DEFAULT_BACKGROUND, Camera
from tessera.scheduling import actions
from tessera.scheduling.frame_jobs import DEFAULT_SESSION, FrameJob
from tessera.scheduling.job_scheduler import JobScheduler
from tessera.wire import messages
from tessera.wire.messages import (
    Calibration,
    Cancel,
    LevelsReady,
    Message,
    NodeHello,
    RenderError,
    SceneError,
    SceneProgress,
    SceneReady,
    ShareSpec,
    TilesDropped,
    TileSent,
    Welcome,
)
from tessera.wire.pick_messages import PickResult
from tessera.wire.protocol import ProtocolError, unpack_tile

log = logging.getLogger("tessera.server")

class SessionsFull(RuntimeError):
    """``--max-sessions`` sessions are open."""


#: Longest wait of the timer task between two looks at the scheduler and calibration (s).
TIMER_MAX_WAIT_S = 1.0


class RenderService(SessionPersistence, ServiceReport):
    """The coordinator's I/O: the nodes' links, calibration, the sessions (:class:`Session`: each
    with its frame store and viewers) and the scheduler they share. ``library`` resolves the scene
    names sessions are made from. Saving and restoring sessions: :class:`SessionPersistence`;
    ``/api/stats``: :class:`ServiceReport`."""

    def __init__(self, settings: Settings, metrics: CoordinatorMetrics | None = None,
                 library: SceneLibrary | None = None) -> None:
        self.settings = settings
        self.size = settings.size
        self.metrics = metrics or CoordinatorMetrics()
        self.library = library
        self.scheduler = JobScheduler(settings.scheduler_config(), create_balancer(settings.balancer),
                                        settings.scene)
        self.scheduler.default.stats = ObservedFrameStats(self.metrics)
        if settings.local_nodes:   # sort-last shares are cut once they joined (or the wait ran out)
            self.scheduler.expect_nodes(settings.local_nodes, time.monotonic() + LOCAL_NODES_JOIN_S)
        self.nodes: dict[int, NodeLink] = {}
        self.still_executor: Executor = ThreadPoolExecutor(1, thread_name_prefix="tessera-still")
        self.default = Session(self, DEFAULT_SESSION, settings.scene)
        self.sessions: dict[str, Session] = {DEFAULT_SESSION: self.default}
        self._watch_keys: dict[str, str] = {self.default.watch_key: DEFAULT_SESSION}
        self._fetch: dict[str, tuple[str, str]] = {}
        self.session_store = None if settings.data_dir is None else SessionStore(settings.data_dir)
        self._session_writer = ThreadPoolExecutor(1, thread_name_prefix="tessera-sessions")
        #: A session was opened, closed or changed since they were last saved.
        self.changed_sessions = False
        self._sessions_opened = 0
        self._next_node_id = 1
        self._wake = asyncio.Event()
        self._tasks: list[asyncio.Task] = []
        self.cpu_ms = {"receive": 0.0, "publish": 0.0, "merge": 0.0}
        self.calibration = NodeCalibration(self)
        #: Picks waiting for their nodes' answers, posters and films (issue 35).
        self.picks = PickDesk(self)
        self.jobs = RenderJobs(self, settings.max_jobs)
        #: Meshes sent as arrays (issue 33: ``PUT /api/sessions/{id}/mesh``).
        self.meshes = MeshUpdates(self)
        self._meshes_saved: dict[str, str] = {}
        if self.session_store is not None:
            self._restore_sessions()

    @property
    def store(self) -> FrameStore:
        return self.default.store

    @property
    def viewers(self) -> ViewerHub:
        return self.default.viewers

    @property
    def bounds(self) -> np.ndarray | None:
        return self.default.bounds

    @property
    def camera(self) -> Camera | None:
        return self.default.camera

    # ----------------------------------------------------------------- sessions
    def fetch_of(self, scene: str) -> tuple[str, str] | None:
        """Where a node fetches scene file ``scene`` (its URL and sha256), if it is a library file."""
        return self._fetch.get(scene)

    def find_session(self, key: str, watch: bool = False) -> Session | None:
        """The session ``key`` drives (its id), or with ``watch`` the one it watches (its watch key)."""
        session_id = self._watch_keys.get(key) if watch else key
        return self.sessions.get(session_id) if session_id is not None else None

    def create_session(self, scene: str, size: tuple[int, int] | None = None, camera: Camera | None = None,
                       spec: str | None = None, fetch: tuple[str, str] | None = None,
                       wall: WallLayout | None = None) -> Session:
        """A session showing library scene ``scene`` (``spec``: what nodes load, default the name;
        ``fetch``: the file's URL on this coordinator and its sha256, for nodes without it) at
        ``size`` (default ``--size``; a ``wall``'s: the whole wall); SessionsFull when
        ``--max-sessions`` are open."""
        if len(self.sessions) >= self.settings.max_sessions:
            raise SessionsFull(f"{len(self.sessions)} sessions are open, the most this coordinator serves "
                               "(--max-sessions); close one or try later")
        self._sessions_opened += 1
        return self._open(Session(self, new_key(), spec or scene, scene, label=str(self._sessions_opened),
                                  wall=wall), size, camera, fetch)

    def _open(self, session: Session, size: tuple[int, int] | None, camera: Camera | None,
              fetch: tuple[str, str] | None) -> Session:
        if fetch is not None:
            self._fetch[session.scene] = fetch
        size = session.wall.size if session.wall is not None else size
        config = dataclasses.replace(self.settings.scheduler_config(), size=size or self.settings.size)
        self.sessions[session.id] = session
        self._watch_keys[session.watch_key] = session.id
        self.scheduler.add_session(session.id, config, create_balancer(self.settings.balancer), session.scene,
                                   time.monotonic())
        session.frames.wall = session.wall
        if camera is not None:
            self.scheduler.set_camera(camera, time.monotonic(), session_id=session.id)
        self.apply()
        self.changed_sessions = True
        log.info("session %s… opened: %s at %dx%d", session.id[:6], session.name, *config.size)
        return session

    def switch_scene(self, session: Session, name: str, spec: str, fetch: tuple[str, str] | None,
                     camera: Camera | None = None, held: Mapping[int, SceneReady] | None = None,
                     keep_partition: bool = False) -> int:
        """``session`` shows library scene ``name`` (``spec``: what nodes load; ``fetch`` as in
        :meth:`create_session`) from now on, with its size, balancer, viewers and frame store, its
        camera kept unless ``camera`` is given. Its frames in flight are dropped, so the next frame
        published is the new scene's, whole; until then viewers keep the old scene's last frame.
        ``held``: the nodes that hold it already (a mesh loaded ahead) and their ``scene_ready``:
        ready at once, together, sent no load. ``keep_partition``: the balancer goes on from the old
        scene's partition (a mesh step, drawn much as the one before). Returns the first frame id
        that can show the new scene."""
        now = time.monotonic()
        if fetch is not None:
            self._fetch[spec] = fetch
        balancer, size = session.balancer, session.size
        camera = camera or session.camera
        self.jobs.session_closed(session.id)
        for node in self.scheduler.nodes.values():   # the new scene's state versions start afresh: send them whole
            if node.state_sent is not None and node.state_sent[0] == session.id:
                node.state_sent = None
        session.scene, session.name, session.bounds, session.state, session.error = spec, name, None, "loading", None
        config = dataclasses.replace(self.settings.scheduler_config(), size=size)
        self.scheduler.replace_session(session.id, config, create_balancer(balancer.name, balancer.params), spec, now,
                                       held=held or {}, keep_partition=keep_partition)
        session.frames.wall = session.wall
        self.allow_for_shown_scenes()
        first = self.scheduler.next_frame_id
        if camera is not None:
            first = self.scheduler.set_camera(camera, now, session_id=session.id)
        if held:
            adopt_scene(self.scheduler, session, next(iter(held.values())), now)
            self.scheduler.nodes_ready(list(held), now, session_id=session.id)
        self.apply()
        self.changed_sessions = True
        log.info("session %s… now shows %s", session.id[:6], name)
        return first

    # ----------------------------------------------------------------- lifecycle
    async def start(self) -> None:
        self._tasks = [asyncio.create_task(self._timer(), name="scheduler-timer")]

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self.save_sessions()
        await asyncio.to_thread(self._session_writer.shutdown, wait=True)   # every write asked is done
        self.still_executor.shutdown(wait=False, cancel_futures=True)
        await asyncio.to_thread(self.jobs.close)

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
                self.apply()
            if now >= calibration_at + TIMER_MAX_WAIT_S:
                calibration_at = now
                self.calibration.advance()
                self._collect_idle_sessions(now)
                if self.changed_sessions:
                    self.save_sessions()

    def apply(self) -> None:
        """Carry out the scheduler's actions, then let the timer look at the new deadline."""
        for action in self.scheduler.drain():
            if isinstance(action, actions.RenderTiles):
                self.nodes[action.node_id].send(action.message)
            elif isinstance(action, actions.CancelFrames):
                self.nodes[action.node_id].send(Cancel(frames=action.frames))
            elif isinstance(action, actions.LoadScene):
                self.meshes.before_load(action.node_id, action.scene)
                self.nodes[action.node_id].send(self.load_message(action.scene, action.share))
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

    def add_node(self, hello: NodeHello, close, local: bool = False) -> NodeLink:
        """A node that said ``hello`` joins (``local``: from this machine; ``close(code, reason)``
        closes its socket)."""
        name, renderer = hello.name[:64] or "node", hello.renderer[:200]
        link = NodeLink(self._next_node_id, name, renderer, close, slowdown=hello.capabilities.slowdown,
                        can_calibrate=hello.capabilities.calibrate)
        self._next_node_id += 1
        self.nodes[link.node_id] = link
        link.send(Welcome(node_id=link.node_id))
        self.scheduler.add_node(link.node_id, time.monotonic(), local, hello.host)
        self.apply()   # the scene to load (sort-last: every node's share of the new partition)
        log.info("node %d (%s) joined: %s", link.node_id, name, renderer)
        return link

    def load_message(self, scene: str | None, share: ShareSpec | None = None) -> messages.LoadScene:
        """Load ``scene`` (None: ``--scene``), with where to fetch it for a session's library file."""
        spec = scene or self.settings.scene
        url, sha256 = self._fetch.get(spec, (None, None))
        levels = True if self.settings.lod_error_px > 0.0 and self.settings.mode != "hybrid" else None
        return messages.LoadScene(scene=spec, background=self.settings.background or DEFAULT_BACKGROUND, share=share,
                                  url=url, sha256=sha256, levels=levels)

    def remove_node(self, link: NodeLink) -> None:
        """The node's connection ended: what it owed goes to the others."""
        if self.nodes.get(link.node_id) is not link:
            return
        schedule = self.scheduler.nodes.get(link.node_id)
        log.info("node %d (%s) left; %d tiles owed are re-dispatched", link.node_id, link.name,
                 len(schedule.outstanding) if schedule is not None else 0)
        self._forget_node(link)
        self.scheduler.remove_node(link.node_id, time.monotonic())
        self.apply()

    def _forget_node(self, link: NodeLink) -> None:
        self.nodes.pop(link.node_id, None)
        self.calibration.forget(link.node_id)
        self.picks.node_left(link.node_id)

    def send_to(self, node_id: int, message: Message) -> bool:
        """Send ``message`` to node ``node_id``; False when it is gone."""
        link = self.nodes.get(node_id)
        if link is not None:
            link.send(message)
        return link is not None

    def on_node_message(self, link: NodeLink, message: Message) -> None:
        """A control message of :data:`tessera.wire.messages.FROM_NODE` from ``link``."""
        match message:
            case SceneProgress():
                link.progress, link.scene_message = message.fraction, message.message[:200]
                link.loading[message.scene] = (message.fraction, link.scene_message)
                link.rss_mb = message.rss_mb if message.rss_mb is not None else link.rss_mb
            case SceneReady():
                self._on_scene_ready(link, message)
            case LevelsReady():
                tables = None if None in (message.group_errors, message.group_triangles, message.group_boxes) else \
                    (np.asarray(message.group_errors), np.asarray(message.group_triangles),
                     np.asarray(message.group_boxes))
                for session in self._showing(message.scene):
                    self.scheduler.levels_ready(link.node_id, session.id, tables)
                self.apply()
            case SceneError():
                link.loading.pop(message.scene, None)
                if self.meshes.failed_ahead(link.node_id, message.scene):   # a mesh step loading ahead, or passed over
                    return
                link.state, link.scene_message = "error", message.message[:500]
                log.error("node %d (%s) could not load the scene: %s", link.node_id, link.name, link.scene_message)
                for session in self._showing(message.scene):
                    if session.state != "ready":
                        session.state, session.error = "error", link.scene_message
                    self.scheduler.scene_failed(link.node_id, session.id)
                self.apply()
            case TileSent():
                if link.last_tile != (message.frame, message.tile):
                    raise ProtocolError(f"tile_sent for tile {message.tile} of frame {message.frame}, which is not "
                                        "the tile this node just sent")
                link.last_tile = None
                link.rss_mb = message.rss_mb if message.rss_mb is not None else link.rss_mb
                self.scheduler.tile_sent(link.node_id, message.frame, message.tile, message.send_ms, message.stats)
                self.metrics.tile_sent(message.send_ms)
            case TilesDropped():
                self.scheduler.tiles_skipped(link.node_id, message.frame, message.tiles)
                link.tiles_dropped += len(message.tiles)
            case Calibration():
                self.calibration.measured(link, message.ms)
            case RenderError():
                self._on_render_error(link, message.frame, message.tile, message.message[:300])
            case PickResult():
                self.picks.answered(link.node_id, message)

    def _on_render_error(self, link: NodeLink, frame_id: int, tile_id: int, reason: str) -> None:
        """A tile the node could not render goes to another node (the scheduler decides when a node
        fails too often); frame 0 is a failed calibration: the node keeps its speed."""
        log.warning("node %d (%s) could not render tile %d of frame %d: %s", link.node_id, link.name, tile_id,
                    frame_id, reason)
        if frame_id == 0:
            self.calibration.failed(link)
            return
        self.scheduler.tile_failed(link.node_id, frame_id, tile_id, time.monotonic())
        self.apply()

    def _showing(self, scene: str | None) -> list[Session]:
        """The sessions whose nodes load ``scene`` (None: a node that does not say, the default's)."""
        spec = scene or self.settings.scene
        return [s for s in self.sessions.values() if s.scene == spec]

    def allow_for_shown_scenes(self, links: Iterable[NodeLink] | None = None) -> None:
        """Each node's tiles may take as long as the largest scene a session shows on it takes to
        draw (:meth:`FrameScheduler.node_holds`): a huge scene closed no longer stretches the time
        after which the node counts as silent. Over every node (``links`` None: a session closed or
        switched scene) what it held of scenes no session shows is forgotten
        (:meth:`NodeLink.forget_scenes_not_shown`)."""
        shown = {session.scene for session in self.sessions.values()}
        for link in self.nodes.values() if links is None else links:
            if links is None:
                link.forget_scenes_not_shown(shown)
            self.scheduler.node_holds(link.node_id, max(
                (n for spec, n in link.scene_triangles.items() if spec in shown), default=0))

    def _on_scene_ready(self, link: NodeLink, message: SceneReady) -> None:
        """A node holds ``message``'s scene: the sessions showing it may draw on it. It is calibrated
        (on the default session's scene) when that is the scene it reports, not again for another
        session's: its speed is the same, and a calibration holds up its tiles of every session while
        it draws the region three times, then reweights every session's partition with a time taken
        on a loaded machine (the speeds swung between 1.0 and 2.3 from one to the next in
        ``bench.sessions``, each time a node held the new session's scan)."""
        bounds = np.asarray(message.bounds, dtype=np.float64)
        link.bounds, link.triangles, link.share = bounds, message.triangles, message.share
        link.state, link.progress, link.scene_message = "ready", 1.0, "ready"
        spec = message.scene or self.settings.scene
        link.loading.pop(spec, None)
        if message.scene_mb is not None:
            link.scene_mb[spec] = message.scene_mb
        link.held_mb = message.held_mb if message.held_mb is not None else link.held_mb
        link.rss_mb = message.rss_mb if message.rss_mb is not None else link.rss_mb
        now = time.monotonic()
        link.scene_triangles[spec] = message.triangles + (message.points or 0)   # a point counts as a triangle
        self.allow_for_shown_scenes([link])
        showing = self._showing(message.scene)
        if not showing and self.meshes.loaded_ahead(link.node_id, message):
            return
        for session in showing:
            if session.bounds is None:
                adopt_scene(self.scheduler, session, message, now)
            self.scheduler.node_ready(link.node_id, now, message.share, session.id)
        log.info("node %d (%s) ready: %s, %d triangles%s", link.node_id, link.name,
                 message.scene or self.settings.scene, link.triangles,
                 "" if message.share is None else f", its share of partition {message.share}")
        self.apply()
        if link.can_calibrate and self.default in showing:
            self.calibration.request([link.node_id])

    # ----------------------------------------------------------------- calibration (seed 003 §1)
    def calibrate_all(self) -> list[int]:
        """Measure every ready node that can calibrate again; returns their ids."""
        ids = [n.node_id for n in sorted(self.nodes.values(), key=lambda n: n.node_id) if n.ready and n.can_calibrate]
        self.calibration.request(ids)
        return ids

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
            self.apply()
        finally:
            spent = (time.thread_time() - started) * 1000.0
            self.cpu_ms["receive"] += spent - (self.cpu_ms["publish"] - published_before)

    def _frame_tiles(self, job: FrameJob) -> list:
        """What viewers get of ``job`` (the mode's assembly; a merge's CPU time is accounted)."""
        if not self.scheduler.sessions[job.session].mode.merges:
            return self.scheduler.viewer_tiles(job)
        started = time.thread_time()
        tiles = self.scheduler.viewer_tiles(job)
        self.cpu_ms["merge"] += (time.thread_time() - started) * 1000.0
        return tiles

    def _publish(self, job: FrameJob) -> None:
        session = self.sessions.get(job.session)
        if session is None:
            return
        if job.job is not None:   # a render job's tile (issue 35; sort-last's merged as a still's sample is)
            self.jobs.tile(job, self._frame_tiles(job) if job.depth is not None else None)
            return
        if job.samples > 1:
            self._refine(session, job)
            return
        self._show(session, job, self._frame_tiles(job))

    def _show(self, session: Session, job: FrameJob, tiles: list, refined: Refined | None = None) -> None:
        """Publish ``job`` to the session's store and viewers with ``tiles``; ``refined``: what a
        progressive still's sample made (then the frame is the still once it converged)."""
        started = time.thread_time()
        state = job.state
        frame = PublishedFrame(job.frame_id, job.camera, job.size, tiles, time.monotonic(),
                               still=job.still and (refined is None or refined.converged), inputs=job.inputs,
                               state_version=None if state is None else state.version,
                               scene_time=None if state is None else state.time,
                               tile_states=tuple(t.header.state if t.header else 0 for t in job.tiles),
                               samples=0 if refined is None else refined.samples,
                               estimate_db=None if refined is None else refined.estimate_db)
        session.store.add(frame)
        self.meshes.published(session.id, job.frame_id)
        if session.viewers.slots:
            session.viewers.publish_frame(frame)
        self.cpu_ms["publish"] += (time.thread_time() - started) * 1000.0

    def _refine(self, session: Session, job: FrameJob) -> None:
        """A progressive still's sample (issues 20, 37): accumulated on the still thread
        (:class:`server.still_refinement.StillRefiner`), the running mean published when it is done
        and shown (the converged one, refinements of enough samples) unless something changed since
        (input cancels the refinement at once); once converged, the scheduler stops the samples."""
        codec, quality = self.scheduler.sessions[job.session].codec(True)
        done = session.refiner.submit(job.sample, job.plan, job.size, self._frame_tiles(job), codec, quality,
                                      refinements=job.point_spacing_px is None)
        loop = asyncio.get_running_loop()

        def back_to_the_loop(future: Future) -> None:
            with contextlib.suppress(RuntimeError):   # the loop closed: the coordinator stopped
                loop.call_soon_threadsafe(self._refined, session, job, future)

        done.add_done_callback(back_to_the_loop)

    def _refined(self, session: Session, job: FrameJob, done: Future) -> None:
        session.refiner.taken()
        if done.cancelled():
            return
        if done.exception() is not None:
            log.error("session %s… still sample %d not accumulated: %s", session.id[:6], job.sample, done.exception())
            return
        frames = self.scheduler.sessions.get(job.session)
        refined: Refined | None = done.result()
        if (refined is None or self.sessions.get(session.id) is not session or frames is None
                or frames.demand.version != job.version or job.frame_id <= session.store.last_id):
            return
        if refined.converged:
            self.scheduler.still_converged(time.monotonic(), job.version, job.session)
        self._show(session, job, refined.tiles, refined)
        if refined.converged:
            self.apply()
