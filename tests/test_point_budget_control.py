"""A point cloud session's point budget while its picture moves (issue 36,
:mod:`tessera.scheduling.point_budget_control`): lowered down to the floor while frames are slow
(faster when far too slow), raised up to the ceiling while they are quick, held inside the band; a
start outside the bounds widens them."""

from __future__ import annotations

import pytest

from tessera.scheduling.lod_control import FAR, HOLD, QUICK, SLOW, STEP
from tessera.scheduling.point_budget_control import PointBudgetControl

TARGET_FPS = 10.0
INTERVAL = 1.0 / TARGET_FPS


def frames_until(control: PointBudgetControl, busy_s: float, budget: int, limit: int = 100) -> int:
    """Frames of ``busy_s`` each until ``control``'s budget is ``budget``."""
    for count in range(1, limit + 1):
        control.frame_done(busy_s)
        if control.budget == budget:
            return count
    raise AssertionError(f"the budget stopped at {control.budget}, not {budget}")


@pytest.mark.parametrize(("busy", "first", "bound"), [(2.0 * INTERVAL, 200_000, 50_000),
                                                    (0.1 * INTERVAL, 450_000, 1_000_000)])
def test_slow_frames_lower_the_budget_and_quick_ones_raise_it_step_by_step_to_its_bound(busy, first, bound):
    control = PointBudgetControl(300_000, 50_000, 1_000_000, TARGET_FPS)
    assert frames_until(control, busy, first) == HOLD
    frames_until(control, busy, bound)
    for _ in range(3 * HOLD):
        control.frame_done(busy)
    assert control.budget == bound


def test_frames_far_too_slow_lower_it_by_two_steps_at_every_frame():
    control = PointBudgetControl(900_000, 10_000, 1_000_000, TARGET_FPS)
    control.frame_done(1.01 * FAR * INTERVAL)
    assert control.budget == 400_000
    control.frame_done(1.01 * FAR * INTERVAL)
    assert control.budget == round(400_000 / STEP ** 2)


@pytest.mark.parametrize("busy", [0.99 * SLOW * INTERVAL, 1.01 * QUICK * INTERVAL])
def test_frames_inside_the_band_hold_the_budget(busy):
    control = PointBudgetControl(300_000, 50_000, 1_000_000, TARGET_FPS)
    control.pace.smoothed_s = busy
    for _ in range(10 * HOLD):
        control.frame_done(busy)
    assert control.budget == 300_000


def test_a_start_outside_the_bounds_widens_them_and_equal_bounds_fix_the_budget():
    low = PointBudgetControl(25_000, 100_000, 3_000_000, TARGET_FPS)
    assert (low.budget, low.floor, low.ceiling) == (25_000, 25_000, 3_000_000)
    high = PointBudgetControl(5_000_000, 100_000, 3_000_000, TARGET_FPS)
    assert (high.budget, high.ceiling) == (5_000_000, 5_000_000)
    fixed = PointBudgetControl(300_000, 300_000, 300_000, TARGET_FPS)
    for busy in (10.0, 10.0, 10.0, 0.0, 0.0, 0.0, 0.0):
        fixed.frame_done(busy)
    assert fixed.budget == 300_000


def test_bad_bounds_are_refused():
    with pytest.raises(ValueError):
        PointBudgetControl(0, 1, 2, TARGET_FPS)
    with pytest.raises(ValueError):
        PointBudgetControl(10, 1, 20, 0.0)
