"""One session's picture on the shared cluster (issue 19): its own frame size, decomposition mode
and balancer, camera, scene state, render-on-demand versions, viewers' input numbers, frames in
flight and figures. The frame scheduler (:mod:`tessera.scheduling.scheduler`) holds one per
session and shares the nodes among them. Pure: the clock comes in as ``now`` (s)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Hashable, Sequence

import numpy as np

from tessera.balancers.base import Balancer, Partition, ProjectedGroups, Tile
from tessera.balancers.partition import equal_strip_partition
from tessera.balancers.projection import GroupProjector
from tessera.compositing.layers import background_pixel
from tessera.decomposition.mode import DecompositionMode
from tessera.decomposition.modes import create_mode
from tessera.decomposition.wall_cells import WallLayout
from tessera.geometry import DEFAULT_BACKGROUND, Camera, Rect, near_far_from_bounds
from tessera.scene.state import SceneState, StateDelta
from tessera.scene.timeline import SceneTimeline
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.frame_stats import FrameStats
from tessera.scheduling.lod_control import LodControl
from tessera.scheduling.node_table import NodeSchedule
from tessera.scheduling.point_budget_control import PointBudgetControl
from tessera.scheduling.refinement import ONE_FRAME
from tessera.scheduling.render_demand import RenderDemand
from tessera.tools.clipping import ClipState
from tessera.wire.codec import Codec


class SessionFrames:
    """Session ``session_id``: ``scene_key`` is the scene its nodes load (None: the coordinator's
    own); ``ready`` the nodes that hold it; ``frames`` its frames in flight by id; ``charges`` what each
    was charged of node time and its scarcity (:class:`tessera.scheduling.fair_share.FairShare`)."""

    def __init__(self, session_id: str, config, balancer: Balancer, scene_key: str | None = None) -> None:
        self.id = session_id
        self.config = config
        self.scene_key = scene_key
        self.mode: DecompositionMode = create_mode(config.mode, config.size, balancer,
                                                   background_pixel(config.background or DEFAULT_BACKGROUND),
                                                   config.depth_strip)
        self.camera: Camera | None = None
        #: The scene's objects, animations and state log (None: frames show the base pose).
        self.scene: SceneTimeline | None = None
        self.demand = RenderDemand(config.settle_frames, config.still_delay_s, config.still_codec is not None,
                                   config.still_plan)
        self.inputs: dict[Hashable, int] = {}
        #: Projected primitive groups for a camera and the frame's scene state (None: the base pose)
        #: (seed 003 DPBP), for balancers that use them.
        self.groups_for: Callable[[Camera, SceneState | None], ProjectedGroups | None] | None = None
        self._projector: GroupProjector | None = None
        self.stats = FrameStats()
        self.frames: dict[int, FrameJob] = {}
        self.charges: dict[int, tuple[float, float]] = {}
        self.awaiting_send: dict[int, FrameJob] = {}
        self.next_start_at = 0.0
        self.ready: set[int] = set()
        #: Nodes that hold the levels of detail of its scene, and its moving frames' bound.
        self.levels: set[int] = set()
        self.lod = LodControl(config.lod_error_px, config.lod_max_error_px, config.target_fps)
        #: A point cloud's moving frames' budget (issue 36), from their frame times as the bound.
        self.points = PointBudgetControl(config.point_budget, config.point_budget_min, config.point_budget_max,
                                         config.target_fps)
        #: Nodes yet to be told to load the scene, one after the other (the scheduler's ``_load_next``).
        self.loads_waiting: list[int] = []
        #: Nodes told to load the scene that have not answered yet (a node joining meanwhile waits its turn).
        self.loading: set[int] = set()
        self.frames_cancelled = 0
        #: A display wall's cells (issue 22): each frame's partition is cut at their edges (the
        #: pieces of a tile name it: a node draws it once).
        self.wall: WallLayout | None = None
        #: JPEG quality of interactive tiles while a viewer takes the session as video (issue 21):
        #: the tiles are the encoder's source, decoded on the coordinator (None: no video viewer).
        self.video_source_quality: int | None = None
        #: Every viewer of the session takes it as video (issue 21): interactive tiles from nodes on
        #: the coordinator's machine come raw, the encoder's source without a lossy step.
        self.video_only = False
        #: The clip planes and section box its frames are cut by, and the object drawn selected
        #: (issue 35): frame-synchronous, bound when a frame starts (None: none).
        self.clip: ClipState | None = None
        self.highlight: str | None = None
        #: A point cloud's bounds (issue 36: :meth:`set_points`); None: a mesh.
        self.point_bounds: np.ndarray | None = None
        #: A new scene is on its way (issue 33: a mesh step loaded ahead on the nodes, which the
        #: session switches to next): its frame goes first, as a first frame does (:attr:`goes_first`).
        self.scene_coming = False
        #: It took the place of the session of the same id showing another scene (a switch of scene).
        self.replaced = False

    @property
    def size(self) -> tuple[int, int]:
        return self.config.size

    def owed(self, now: float, ignore_quiet: bool = False) -> str | None:
        """"interactive", "still" or None: the kind of frame the session's state asks for at ``now``."""
        if self.camera is None:
            return None
        # A frame cut into pieces teaches the balancer nothing: a settle frame beside it would draw
        # the same picture again on the same few nodes (a session's first frame took twice as long).
        moving = self.demand.settling and self.mode.tiles.moving and not self.pieces_in_flight
        return self.demand.owed(now, self.scene is not None and self.scene.animating, moving,
                                self.interactive_in_flight, ignore_quiet)

    @property
    def pieces_in_flight(self) -> bool:
        """A frame of the session cut into pieces (:attr:`FrameJob.one_by_one`) is in flight."""
        return any(job.one_by_one for job in self.frames.values())

    @property
    def awaits_first_frame(self) -> bool:
        """A node loads its scene, or holds it (or it took another session's place: its nodes are
        told next) and it has a camera, and no frame of it was published yet."""
        return (bool(self.loading or ((self.ready or self.replaced) and self.camera is not None))
                and not self.demand.published_any)

    @property
    def goes_first(self) -> bool:
        """Its first frame, or its next scene's, is awaited: no other session's still sample and
        no calibration starts meanwhile."""
        return self.scene_coming or self.awaits_first_frame

    @property
    def interactive_in_flight(self) -> bool:
        """An interactive frame of the session is in flight (it will show the newest state it took)."""
        return any(not job.still for job in self.frames.values())

    def may_start(self, now: float, idle: set[int]) -> bool:
        """A frame is owed, another may be in flight, and a node holding the scene is ``idle``."""
        return (len(self.frames) < self.config.max_in_flight and now >= self.next_start_at and self.mode.can_start
                and not self.ready.isdisjoint(idle) and self.owed(now) is not None)

    def start_due(self, now: float, idle: set[int]) -> float | None:
        """When a frame owed could start (the frame-rate cap, the still frame's quiet time) while a
        node holding the scene is ``idle``; None: none is owed, or none may start (as
        :meth:`may_start`: sort-last waits for every share, and the share that completes them wakes
        the scheduler)."""
        if len(self.frames) >= self.config.max_in_flight or not self.mode.can_start or self.ready.isdisjoint(idle):
            return None
        owed = self.owed(now, ignore_quiet=True)
        if owed is None:
            return None
        return max(self.next_start_at, self.demand.due(now, owed))

    def start_frame(self, frame_id: int, ready: Sequence[NodeSchedule], now: float,
                    still: bool, raw_tiles: bool = False, pieces: int = 1) -> tuple[FrameJob, str | None]:
        """Frame ``frame_id`` (a still's next sample or an interactive frame) of the newest camera and scene state,
        partitioned by the mode over the ``ready`` nodes that hold the scene; with why the
        balancer failed, if it did (the static split was used). ``raw_tiles``: the tiles are
        asked for raw (a still's samples, accumulated, never shown as they come; a video-only
        session's interactive frames, the encoder's source). ``pieces`` > 1 (not
        for a display wall's session): the frame is cut into that many equal-area pieces handed to
        its nodes one at a time instead (:attr:`FrameJob.one_by_one`), the balancer not asked (it
        learns from its own partitions only)."""
        assert self.camera is not None
        camera, state = self.camera, self.scene.bind(now) if self.scene else None
        groups_for = self.groups_for
        parts: tuple[Rect | None, ...] = ()
        if pieces > 1:
            partition = Partition(tuple(Tile(rect, None) for rect in equal_strip_partition(pieces, self.size)),
                                  pull=True)
        else:
            partition = self.mode.partition([n.node_id for n in ready], {n.node_id: n.speed for n in ready}, now,
                                            lambda: groups_for(camera, state) if groups_for else None)
            if self.wall is not None:
                partition, parts = self.wall.pieces(partition)
        error, self.mode.tiles.error = self.mode.tiles.error, None
        codec, quality = self.codec(still)
        if raw_tiles:
            codec = Codec.RAW
        sample = self.demand.started(still)
        job = FrameJob.create(frame_id, camera, self.size, codec, quality, partition, now, still=still,
                              version=self.demand.version, changed_at=self.demand.changed_at,
                              inputs=dict(self.inputs), state=state, depth=self.mode.depth_request(partition),
                              session=self.id, scene=self.scene_key, sample=sample,
                              plan=self.demand.still_plan if still else ONE_FRAME, parts=parts,
                              clip=self.clip, highlight=self.highlight)
        job.one_by_one = pieces > 1
        job.lod_error_px = None if still else self.lod_bound
        if self.point_bounds is not None:
            self._points_job(job, camera, still)
        self.next_start_at = now + 1.0 / self.config.max_fps
        self.frames[frame_id] = job
        return job, error

    def set_points(self, bounds: np.ndarray) -> None:
        """The scene is a point cloud of ``bounds`` (2, 3) (issue 36): moving frames draw within the
        point budget (:attr:`points`), stills every point in view (where too many are in view, in a
        second pass after the first still converged: :meth:`RenderDemand.points_left_out`);
        sort-last frames are shaded after the merge. A hybrid session turns sort-first (a hybrid
        tile's strip has no depth beyond it to shade from)."""
        self.point_bounds = np.asarray(bounds, np.float64)
        if self.config.mode == "hybrid":
            self.config = dataclasses.replace(self.config, mode="sort-first")
            self.mode = create_mode("sort-first", self.size, self.mode.tiles.balancer, self.mode.background,
                                    self.config.depth_strip)

    def _points_job(self, job: FrameJob, camera: Camera, still: bool) -> None:
        assert self.point_bounds is not None
        job.point_budget = None if still else self.points.budget
        job.point_spacing_px = 0.0 if still and self.demand.every_point else None
        job.point_size = self.config.point_size
        if self.config.mode == "sort-last":
            job.eye_dome = near_far_from_bounds(camera, self.point_bounds)

    @property
    def point_budget(self) -> int | None:
        """The points a moving frame of its point cloud draws at most now (None: a mesh)."""
        return None if self.point_bounds is None else self.points.budget

    @property
    def lod_bound(self) -> float | None:
        """The levels-of-detail bound its moving frames are drawn with now (px; None: full detail):
        none until every node that holds its scene holds its levels (tiles at different levels of
        detail would not join), none in the hybrid mode (a coarse node spans chunks other tiles own)."""
        if self.config.mode == "hybrid" or not self.ready or not self.ready <= self.levels:
            return None
        return self.lod.bound

    @property
    def settled(self) -> bool:
        """Nothing is owed: the newest state was rendered, the still frame too."""
        return not self.frames and self.owed(float("inf")) is None

    def codec(self, still: bool) -> tuple[Codec, int]:
        """The codec and JPEG quality of a still or an interactive frame (interactive tiles that feed
        a video stream: :attr:`video_source_quality`)."""
        config = self.config
        if still:
            assert config.still_codec is not None
            return config.still_codec, config.still_quality
        if self.video_source_quality is not None and config.codec is Codec.JPEG:
            return Codec.JPEG, self.video_source_quality
        return config.codec, config.interactive_quality

    def forget_source(self, source: Hashable) -> None:
        """A viewer left: its input numbers are no longer reported."""
        self.inputs.pop(source, None)

    def timeline(self) -> SceneTimeline:
        """The scene's timeline; RuntimeError before a node reported the scene's objects."""
        if self.scene is None:
            raise RuntimeError("no scene yet: no node has loaded it")
        return self.scene

    def set_groups(self, boxes: np.ndarray, counts: np.ndarray, bounds: np.ndarray,
                   owners: np.ndarray | None = None) -> None:
        """The scene's primitive groups (K, 6), their primitive counts (K,), its bounds (2, 3) and
        each group's object ``owners`` (K,), projected per frame in the session's state and size
        for balancers that use them (seed 003 DPBP; :class:`GroupProjector`)."""
        self._project(GroupProjector(boxes, counts, bounds, owners, self.size))

    def set_group_levels(self, errors: np.ndarray, triangles: np.ndarray, boxes: np.ndarray) -> None:
        """Its primitive groups' levels of detail: (K, L + 1) errors (world units) and triangles,
        (K, L + 1, 6) boxes (:func:`node.scene.lod.group_levels`): from now on the predictions count
        what a frame's bound draws (issue 32)."""
        if self._projector is not None and len(errors) == len(self._projector.counts):
            self._project(self._projector.with_levels(errors, triangles, boxes))

    def _project(self, projector: GroupProjector) -> None:
        self._projector = projector
        self.groups_for = lambda camera, state: projector(camera, state,
                                                          None if self.scene is None else self.scene.graph,
                                                          self.lod_bound)

    def resize(self, size: tuple[int, int]) -> None:
        """Frames from now on are ``size`` (w, h) px: the mode and the groups follow; the
        partition history starts anew (the caller drops the frames in flight)."""
        self.config = dataclasses.replace(self.config, size=size)
        self.mode.resize(size)
        if self._projector is not None:
            self._project(self._projector.for_size(size))

    def state_for(self, node: NodeSchedule, job: FrameJob) -> SceneState | StateDelta | None:
        """What brings ``node`` to ``job``'s state: a delta on the version it was sent last, if that
        was this session's and the log keeps it, else the whole state."""
        state = job.state
        if state is None or self.scene is None:
            return None
        sent = node.state_sent
        base = self.scene.log.get(sent[1]) if sent is not None and sent[0] == self.id else None
        node.state_sent = (self.id, state.version)
        return state if base is None else state.delta_from(base)
