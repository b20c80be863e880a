"""What the frame scheduler is told (:class:`SchedulerConfig`), with the defaults the coordinator's
settings take over."""

from __future__ import annotations

from dataclasses import dataclass

from tessera.decomposition.chunk_ownership import DEFAULT_DEPTH_STRIP
from tessera.decomposition.modes import MODES
from tessera.points.budget import DEFAULT_POINT_BUDGET, DEFAULT_POINT_SIZE
from tessera.scheduling.lod_control import (
    DEFAULT_LOD_ERROR_PX,
    DEFAULT_LOD_MAX_ERROR_PX,
    DEFAULT_TARGET_FPS,
    LodControl,
)
from tessera.scheduling.point_budget_control import (
    DEFAULT_POINT_BUDGET_MAX,
    DEFAULT_POINT_BUDGET_MIN,
    PointBudgetControl,
)
from tessera.scheduling.refinement import DEFAULT_MAX_STILL_SAMPLES, DEFAULT_STILL_TARGET_DB, StillPlan
from tessera.wire.codec import Codec


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
    ``target_fps``: a moving frame's levels-of-detail bound (:mod:`tessera.scheduling.lod_control`);
    ``point_budget`` (where it starts), ``point_budget_min`` and ``point_budget_max`` and
    ``target_fps``: a point cloud's moving frames' budget
    (:mod:`tessera.scheduling.point_budget_control`)."""

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
    #: A point cloud's moving frames draw at most this many points (where the loop starts, within
    #: the min and max); every splat at least this wide (px).
    point_budget: int = DEFAULT_POINT_BUDGET
    point_budget_min: int = DEFAULT_POINT_BUDGET_MIN
    point_budget_max: int = DEFAULT_POINT_BUDGET_MAX
    point_size: float = DEFAULT_POINT_SIZE

    def __post_init__(self) -> None:
        if self.mode not in MODES or self.depth_strip < 0:
            raise ValueError(f"mode must be one of {MODES} and depth_strip >= 0, got {self.mode}, {self.depth_strip}")
        if self.max_in_flight < 1:
            raise ValueError("max_in_flight must be >= 1")
        LodControl(self.lod_error_px, self.lod_max_error_px, self.target_fps)   # raises for a bad bound
        PointBudgetControl(self.point_budget, self.point_budget_min, self.point_budget_max, self.target_fps)
        if not self.point_size > 0.0:
            raise ValueError(f"point_size must be > 0, got {self.point_size}")
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
