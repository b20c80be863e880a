"""A point cloud session's point budget while its picture moves (issue 36): from ``--point-budget``
(where it starts), lowered down to ``floor`` (``--point-budget-min``) while its frames take longer
than ``--target-fps`` allows and raised up to ``ceiling`` (``--point-budget-max``) while they are
quick, so that a moving cloud keeps to the frame rate on any machine: a constant budget tuned on one
machine is too many points on a slower one and too few on a GPU. Pure: frame times come in, the
budget goes out.

The loop is the levels-of-detail bound's (:mod:`tessera.scheduling.lod_control`, issue 32): the same
frame time (the slowest node's busy time), smoothing, band around the target (hysteresis) and
:data:`~tessera.scheduling.lod_control.HOLD` frames between steps; the budget moves by a factor of
:data:`~tessera.scheduling.lod_control.STEP` (STEP² when frames are far too slow). Stills draw
without a budget; the budget is kept for the next motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from tessera.scheduling.lod_control import STEP, FramePace

#: The fewest points the loop lowers a moving frame's budget to (``--point-budget-min``): below it a
#: 1280x720 frame of a large survey shows its coarse levels only, and the frame's cost is mostly what
#: does not depend on the points (eye-dome lighting, read back, encoding).
DEFAULT_POINT_BUDGET_MIN = 100_000
#: The most points the loop raises it to (``--point-budget-max``): what a GPU draws in a few
#: milliseconds (Potree's default budget is 1M).
DEFAULT_POINT_BUDGET_MAX = 3_000_000


@dataclass
class PointBudgetControl:
    """The budget of one session: ``floor`` … ``ceiling`` points, starting at ``start`` (a start
    outside them widens them), aiming at ``target_fps`` frames a second (its frame times: ``pace``)."""

    start: int
    floor: int
    ceiling: int
    target_fps: float
    budget: int = field(init=False)
    pace: FramePace = field(init=False)

    def __post_init__(self) -> None:
        if min(self.start, self.floor, self.ceiling) < 1 or not self.target_fps > 0.0:
            raise ValueError(f"need budgets >= 1 and a target > 0, got {self.start}, {self.floor}, {self.ceiling}, "
                             f"{self.target_fps}")
        self.floor, self.ceiling = min(self.floor, self.start), max(self.ceiling, self.start, self.floor)
        self.budget = self.start
        self.pace = FramePace(self.target_fps)

    def frame_done(self, busy_s: float) -> None:
        """A moving frame took ``busy_s`` seconds of its slowest node."""
        if busy_s < 0.0:
            return
        steps = self.pace.steps(busy_s, self.budget > self.floor, self.budget < self.ceiling)
        if steps:
            self.budget = min(self.ceiling, max(self.floor, round(self.budget / STEP ** steps)))
