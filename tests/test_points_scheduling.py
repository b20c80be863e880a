"""A point cloud's frames on the coordinator (issue 36): moving frames carry the point budget (which
follows their frame times) and size, stills every point; sort-last frames carry near and far for the
EDL after the merge, and a hybrid session turns sort-first. Pure: the frame scheduler, no network."""

from __future__ import annotations

import numpy as np

from tessera.balancers.base import Partition
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera, near_far_from_bounds
from tessera.scheduling.actions import RenderTiles
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig
from tessera.wire.protocol import TileHeader, state_tag

BOUNDS = np.array([[500000.0, 4000000.0, 90.0], [500300.0, 4000300.0, 130.0]])
CAMERA = Camera((500150.0, 3999800.0, 300.0), (500150.0, 4000150.0, 100.0), (0.0, 0.0, 1.0))


def test_moving_frames_carry_the_budget_and_stills_draw_every_point() -> None:
    s = FrameScheduler(SchedulerConfig(size=(320, 180), max_fps=1e6, settle_frames=0, point_budget=12345,
                                       point_size=3.0, still_delay_ms=0.0), StaticBalancer())
    s.sessions["default"].set_points(BOUNDS)
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    s.set_camera(CAMERA, 0.0)
    moving = [a.message for a in s.drain() if isinstance(a, RenderTiles)]
    assert moving and all(m.point_budget == 12345 and m.point_size == 3.0 for m in moving)
    assert all(m.jitter is None for m in moving)


def test_sort_last_frames_are_shaded_after_the_merge_with_the_frames_near_and_far() -> None:
    s = FrameScheduler(SchedulerConfig(size=(320, 180), mode="sort-last", max_fps=1e6, settle_frames=0),
                       StaticBalancer())
    session = s.sessions["default"]
    session.set_points(BOUNDS)
    job_near_far = near_far_from_bounds(CAMERA, BOUNDS)
    assert session.point_bounds is not None and session.config.mode == "sort-last"
    job = FrameJob.create(1, CAMERA, (320, 180), s.config.codec, 90, Partition(()), 0.0)
    session._points_job(job, CAMERA, still=False)
    assert job.eye_dome == job_near_far and job.point_budget == s.config.point_budget
    session._points_job(job, CAMERA, still=True)
    assert job.point_budget is None


def test_a_hybrid_session_of_a_point_cloud_turns_sort_first() -> None:
    s = FrameScheduler(SchedulerConfig(size=(320, 180), mode="hybrid", max_fps=1e6, settle_frames=0),
                       StaticBalancer())
    session = s.sessions["default"]
    session.set_points(BOUNDS)
    assert session.config.mode == "sort-first" and session.mode.name == "sort-first"
    assert session.mode.depth_request(session.mode.partition([1], {1: 1.0}, 0.0, lambda: None)) is None


def moving_budgets(s: FrameScheduler, render_ms: float, frames: int) -> list[int]:
    """The point budgets of ``frames`` moving frames, each drawn by the node in ``render_ms``."""
    budgets = []
    for k in range(frames):
        eye = (CAMERA.eye[0] + k, CAMERA.eye[1], CAMERA.eye[2])
        s.set_camera(Camera(eye, CAMERA.target, CAMERA.up), float(k))
        for action in [a for a in s.drain() if isinstance(a, RenderTiles)]:
            budgets.append(action.message.point_budget)
            job = s.in_flight[action.message.frame]
            for tile in action.message.tiles:
                header = TileHeader(action.message.frame, tile.tile, tile.rect, job.codec, render_ms, 0.0, 0.0,
                                    state_tag(None))
                s.tile_arrived(action.node_id, header, b"", float(k))
                s.tile_sent(action.node_id, action.message.frame, tile.tile, 0.0)
    return budgets


def test_the_budget_follows_the_moving_frames_times_within_its_bounds() -> None:
    s = FrameScheduler(SchedulerConfig(size=(320, 180), max_fps=1e6, settle_frames=0, still_codec=None,
                                       point_budget=300_000, point_budget_min=100_000, point_budget_max=1_000_000,
                                       target_fps=10.0), StaticBalancer())
    session = s.sessions["default"]
    session.set_points(BOUNDS)
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    slow = moving_budgets(s, 250.0, 12)
    assert slow[0] == 300_000 and slow[-1] == 100_000 and slow == sorted(slow, reverse=True)
    assert session.point_budget == 100_000
    quick = moving_budgets(s, 5.0, 40)
    assert quick == sorted(quick) and quick[-1] == 1_000_000



def still_passes(left_out: int) -> list[tuple[int, float | None]]:
    """(sample, point_spacing_px) of each still sample a point cloud's session asks for (a fixed
    still of 3 samples, the coordinator reporting each still converged at its last), its node
    reporting ``left_out`` points in view left out by a sample drawn at the default spacing."""
    s = FrameScheduler(SchedulerConfig(size=(320, 180), max_fps=1e6, settle_frames=0, still_delay_ms=0.0,
                                       still_samples=3), StaticBalancer())
    s.sessions["default"].set_points(BOUNDS)
    s.add_node(1, 0.0)
    s.node_ready(1, 0.0)
    s.set_camera(CAMERA, 0.0)
    asked, now = [], 0.0
    for _ in range(20):
        now += 0.05
        for action in [a for a in s.drain() if isinstance(a, RenderTiles)]:
            job = s.in_flight[action.message.frame]
            spacing = action.message.point_spacing_px
            if job.still:
                asked.append((job.sample, spacing))
            for tile in action.message.tiles:
                s.tile_arrived(1, TileHeader(job.frame_id, tile.tile, tile.rect, job.codec, 5.0, 0.0, 0.0), b"", now)
                s.tile_sent(1, job.frame_id, tile.tile, 0.0, {"points_left_out": left_out if spacing is None else 0})
            if job.still and job.sample == 2:
                s.still_converged(now, job.version)
        s.tick(now)
    return asked


def test_a_still_that_left_points_out_is_followed_by_a_still_of_every_point() -> None:
    """Where a node says a still's sample (at its default spacing) left points in view out, the
    converged still is followed by a still of every point (spacing 0), its samples from the first
    again, and nothing after it; where none was left out, the first still is the last. A change
    starts the first pass again."""
    first, every = [(k, None) for k in range(3)], [(k, 0.0) for k in range(3)]
    assert still_passes(1) == first + every
    assert still_passes(0) == first
    demand = FrameScheduler(SchedulerConfig(size=(320, 180), still_samples=3), StaticBalancer()).default.demand
    demand.changed(0.0)
    demand.started(True)
    demand.points_left_out(demand.version - 1)
    assert demand.still_converged(demand.version) and not demand.every_point, "left out by an older still"
    demand.changed(1.0)
    demand.started(True)
    demand.points_left_out(demand.version)
    assert demand.still_converged(demand.version) and demand.every_point
    demand.changed(2.0)
    assert not demand.every_point, "a change starts the first pass again"
