"""A point cloud's frames on the coordinator (issue 36): moving frames carry the point budget and
size, stills every point; sort-last frames carry near and far for the EDL after the merge, and a
hybrid session turns sort-first. Pure: the frame scheduler, no network."""

from __future__ import annotations

import numpy as np

from tessera.balancers.base import Partition
from tessera.balancers.static import StaticBalancer
from tessera.geometry import Camera, near_far_from_bounds
from tessera.scheduling.actions import RenderTiles
from tessera.scheduling.frame_jobs import FrameJob
from tessera.scheduling.scheduler import FrameScheduler, SchedulerConfig

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
