"""A session's levels-of-detail bound while its picture moves (issue 32,
:mod:`tessera.scheduling.lod_control`): raised up to the ceiling while frames are slow, faster when
they are far too slow, lowered back to the floor when they are quick, held inside the band."""

from __future__ import annotations

import pytest

from tessera.scheduling.lod_control import (
    DEFAULT_LOD_ERROR_PX,
    DEFAULT_LOD_MAX_ERROR_PX,
    DEFAULT_TARGET_FPS,
    FAR,
    HOLD,
    QUICK,
    SLOW,
    STEP,
    LodControl,
)

TARGET_FPS = 10.0
INTERVAL = 1.0 / TARGET_FPS


def frames_to_ceiling(control: LodControl, busy_s: float, limit: int = 100) -> int:
    """Frames of ``busy_s`` each until ``control``'s bound reaches its ceiling."""
    for count in range(1, limit + 1):
        control.frame_done(busy_s)
        if control.bound_px >= control.ceiling_px:
            return count
    raise AssertionError(f"the bound stopped at {control.bound_px} px below {control.ceiling_px}")


def test_slow_frames_raise_the_bound_step_by_step_to_the_ceiling_and_no_further():
    control = LodControl(0.5, 0.5 * STEP ** 3, TARGET_FPS)
    assert frames_to_ceiling(control, 2.0 * INTERVAL) == 3 * HOLD
    control.frame_done(2.0 * INTERVAL)
    assert control.bound_px == control.ceiling_px


def test_frames_far_too_slow_reach_the_ceiling_in_fewer_steps_without_waiting():
    """A model whose frames take seconds: 0.5 -> 1.5 px in two steps of STEP² at most, not three, one
    a frame (before, HOLD frames apart: 6 s of an 8 s motion at 1 frame/s below the ceiling)."""
    slow = frames_to_ceiling(LodControl(0.5, 0.5 * STEP ** 3, TARGET_FPS), 2.0 * INTERVAL)
    far = frames_to_ceiling(LodControl(0.5, 0.5 * STEP ** 3, TARGET_FPS), 1.01 * FAR * INTERVAL)
    assert far == 2 < slow


@pytest.mark.parametrize("busy", [0.99 * SLOW * INTERVAL, 1.01 * QUICK * INTERVAL])
def test_frames_inside_the_band_hold_the_bound(busy):
    control = LodControl(0.5, 2.0, TARGET_FPS, bound_px=1.0, smoothed_s=busy)
    for _ in range(10 * HOLD):
        control.frame_done(busy)
    assert control.bound_px == 1.0


def test_quick_frames_lower_the_bound_back_to_the_floor():
    control = LodControl(0.5, 2.0, TARGET_FPS, bound_px=2.0, smoothed_s=0.1 * INTERVAL)
    for _ in range(10 * HOLD):
        control.frame_done(0.1 * INTERVAL)
    assert control.bound_px == 0.5


def test_without_levels_of_detail_there_is_no_bound():
    control = LodControl(0.0, 2.0, TARGET_FPS)
    control.frame_done(10.0)
    assert control.bound is None and control.bound_px == 0.0


def test_frames_far_too_slow_take_the_default_floor_to_the_ceiling_in_two_steps_and_no_further():
    """Issue 32: the bound rises two steps a frame while frames take over three times the target
    interval, from the default floor (0.5 px) to the default ceiling (1.5 px) and stops there."""
    control = LodControl(DEFAULT_LOD_ERROR_PX, DEFAULT_LOD_MAX_ERROR_PX, DEFAULT_TARGET_FPS)
    assert control.bound_px == DEFAULT_LOD_ERROR_PX
    bounds = []
    for _ in range(4):
        control.frame_done(10.0)
        bounds.append(control.bound_px)
    assert bounds[-1] == bounds[-2] == DEFAULT_LOD_MAX_ERROR_PX
    assert bounds[0] == pytest.approx(DEFAULT_LOD_ERROR_PX * STEP * STEP)
