"""``rotate`` — seed 000 §4.3: tile distribution (rotation) over the damped adaptive partition.

Tiles are not bound to nodes: the coordinator hands them out in list order to whichever node is
free first (at a frame start, the fastest first), each node pulling the next tile until the frame
is done (the pull dispatch of :class:`tessera.scheduling.scheduler.FrameScheduler`). The list is the
``adaptive`` partition (§4.2: strips→tiles, damped edges, same effort estimate) of
``tiles_per_node`` × N tiles of equal estimated effort, ordered heaviest first by last frame's
time — a tile's predicted effort is last frame's measured load inside its rect, i.e. last frame's
tile time when its edges did not move.

How many tiles: the seed hands out N and relies on a node that finishes early moving on to the
next *frame*; with frames in flight capped that helps only across frame boundaries. With more
tiles than nodes the pull also evens out a frame by itself (longest-first list scheduling): with
k equal tiles per node each node usually pulls k, and when the estimate is off the light tiles
fill the gaps. k = 3 by default: on the synthetic maps of tests/test_balancers.py nodes are ≥ 95 %
busy from the 4th frame and ≥ 96 % once edges settle, 98.5 % on a moving hot spot, where k = 1
(the seed's N tiles) is only as good as ``adaptive``. Each tile costs a dispatch and a read-back,
so k is a parameter. Homogeneous clusters, as the seed says: speed weights only convert measured
times to effort, tile shares are equal. Timings are busy time.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

from tessera.balancers.adaptive import AdaptiveBalancer
from tessera.balancers.base import BalanceInput, Partition, Tile


class RotateBalancer(AdaptiveBalancer):
    name = "rotate"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"tau_ms": 200.0, "min_tile_px": 16, "tiles_per_node": 3}

    def validate_params(self) -> None:
        super().validate_params()
        if self.params["tiles_per_node"] < 1:
            raise ValueError("tiles_per_node must be >= 1")

    def partition(self, inputs: BalanceInput) -> Partition:
        """k × N tiles (fewer on screens too small for them, never fewer than N), heaviest first."""
        width, height = inputs.size
        count = max(len(inputs.node_ids), min(self.params["tiles_per_node"] * len(inputs.node_ids),
                                              min(width, height) ** 2 // 4))
        edges, field = self.edges(inputs, [1.0] * count)
        rects = edges.rects(inputs.size)
        effort = [field.total((r.x, r.y, r.x1, r.y1)) for r in rects]
        order = sorted(range(len(rects)), key=lambda i: (-effort[i], i))
        return Partition(tuple(Tile(rects[i], None) for i in order), pull=True)

