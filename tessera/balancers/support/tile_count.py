"""How many tiles a node pulls a frame, held by a loop on the measured per-frame efficiency (issue
37; pure: timings in, a count out).

Tile rotation evens a frame by its last, small tiles; how small they must be, against the stagger
with which nodes come to a frame and the estimate's error, depends on the scene and the frame's
length: with 3 tiles a node the short frames of the bunny and the traffic (17-23 ms, a tile's fixed
cost 0.4-0.5 ms of it) stayed at 0.947-0.951, where 4 reached 0.97-0.978 for 2.5 % more work a
frame; long frames (the Pan, Lucy) reach 0.96 with 3. So each frame's efficiency — its work
spread over the nodes by speed, over its busiest node's time, :func:`frame_efficiency` — is
measured from its tiles' timings, and :class:`TileCountLoop` adds a tile a node while the mean of
the last frames at the count in use is under the target, and takes one back where it stays well
above it and the count below has not been found short lately.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Mapping, Sequence

from tessera.balancers.base import TileTiming
from tessera.balancers.support.load import measured_ms, speed_of

#: Frames measured at a count before it may change, and the most a decision averages.
MIN_FRAMES = 8
HISTORY = 12
#: Standard errors of the mean by which it must be under the target for a tile a node more (a
#: frame's efficiency scatters by 0.01-0.03).
Z_RAISE = 1.0
#: How far above the target the mean must be for a tile a node less (a tile less raises the
#: frame's stagger and last-tile loss by about this much on the paths measured).
LOWER_MARGIN = 0.02
#: Frames after a count was found under the target before the loop goes back to it.
RETRY_FRAMES = 240
#: Time constants of the edges' damping after the start and after each change before frames are
#: measured: until the edges settle a frame's loss is theirs, which more tiles would not mend (a
#: new count moves every edge, and 16 nodes' edges take 4 time constants to settle).
SETTLE_TAUS = 4.0
#: Frames measured after the start and after each change before they count, however long (the
#: Pan's 80 ms frames settle 4 time constants of ``rotate-predict`` in 3 frames, not its edges).
SETTLE_FRAMES = 8


def frame_efficiency(timings: Sequence[TileTiming], node_ids: Sequence[int], weights: Mapping[int, float]) -> float:
    """A frame's efficiency from its tiles' ``timings``: its effort (measured ms × the drawing
    node's speed weight) spread over ``node_ids`` by speed, over the busiest node's measured ms;
    1 for a frame of no measured time."""
    busy: dict[int, float] = {}
    effort = 0.0
    for timing in timings:
        ms = measured_ms(timing)
        busy[timing.node_id] = busy.get(timing.node_id, 0.0) + ms
        effort += ms * speed_of(weights, timing.node_id)
    speeds = sum(speed_of(weights, n) for n in set(node_ids) | set(busy))
    slowest = max(busy.values(), default=0.0)
    return min(effort / speeds / slowest, 1.0) if slowest > 0.0 else 1.0


class TileCountLoop:
    """Tiles a node between ``lowest`` and ``highest``, starting at ``lowest``, held so that the
    mean measured efficiency of the last frames at it is at least ``target`` (0: the count stays);
    frames count from :data:`SETTLE_TAUS` × ``tau_ms`` (the edges' damping) of partitions and
    :data:`SETTLE_FRAMES` frames after the start and after each change."""

    def __init__(self, lowest: int, highest: int, target: float, tau_ms: float) -> None:
        self.lowest, self.highest, self.target = lowest, max(highest, lowest), target
        self.settle_ms = SETTLE_TAUS * tau_ms
        #: ms of partitions and frames measured since the start or the last change
        self.since_ms, self.seen = 0.0, 0
        self.count = lowest
        #: efficiencies measured at ``count`` since it was set (the last :data:`HISTORY`)
        self.samples: list[float] = []
        #: count → frame (of :meth:`observe`'s) at which it was last found under the target
        self.short: dict[int, int] = {}
        self.frames = 0

    def wait(self, elapsed_ms: float) -> None:
        """``elapsed_ms`` more of partitions at the count in use."""
        self.since_ms += max(elapsed_ms, 0.0)

    def observe(self, efficiency: float, count: int) -> int:
        """One frame's measured ``efficiency``, partitioned at ``count`` tiles a node: the count
        for the next partition."""
        self.frames += 1
        if self.target <= 0.0 or count != self.count:
            return self.count
        self.seen += 1
        if self.since_ms < self.settle_ms or self.seen <= SETTLE_FRAMES:
            return self.count
        self.samples = [*self.samples, efficiency][-HISTORY:]
        if len(self.samples) < MIN_FRAMES:
            return self.count
        mean = statistics.fmean(self.samples)
        error = statistics.stdev(self.samples) / math.sqrt(len(self.samples))
        below = self.count - 1
        if mean + Z_RAISE * error < self.target and self.count < self.highest:
            self.short[self.count] = self.frames
            self.count += 1
        elif (mean >= self.target + LOWER_MARGIN and below >= self.lowest
              and self.frames - self.short.get(below, -RETRY_FRAMES) >= RETRY_FRAMES):
            self.count = below
        else:
            return self.count
        self.samples, self.since_ms, self.seen = [], 0.0, 0
        return self.count
