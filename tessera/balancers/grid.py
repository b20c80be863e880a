"""``grid`` — seed 002 §3.2: grid time-weight balancing with median cut and an imbalance trigger.

The screen is a fine uniform grid of about ``cell_px`` pixel cells (never coarser than the
minimum tile, so tiny screens still hold N tiles); each cell weight starts at 1. After each frame
every node's measured time is spread over the cells of its region into the load-weight table
(:class:`tessera.balancers.support.table.LoadTable`). ``memory`` = 0 is the plain spread; the
default 0.8 keeps the detail earlier frames revealed, our reading of §3.2's "combining the nodes'
history of render times". Cells are the resolution of every cut; the default memory and the 8 px
cell were chosen on synthetic load maps (see the design notes).

The partition is a median cut along cell boundaries: a binary tree over the nodes
(:mod:`tessera.balancers.support.tree`) cuts each region along its longer side in the ratio
k:(N−k) of its subtrees' node counts (speed weights when nodes differ), the cut found by binary
search in the table's summed-area table. The table is normalised by its total implicitly: only
ratios of its sums are used.

Trigger (§3.2 step 4): the previous partition is kept while slowest / fastest node time ≤
``threshold`` (the seed chose it by experiment and reports that too small a value re-partitions
constantly); a frame where a node has no time, or a node change, re-partitions.

The seed measures "render time" on nodes whose render time ran to the end of the framebuffer
read-back, i.e. everything a node did for its tile; we count busy time (render, read-back,
encode, send) by default, ``render_only`` = True counts render time alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from tessera.balancers.base import BalanceInput, Balancer, Partition
from tessera.balancers.static import minimum_for
from tessera.balancers.support.load import node_times
from tessera.balancers.support.table import LoadTable
from tessera.balancers.support.tree import Box, SplitNode, build_tree, split_boxes, to_partition


def median_cut(summed: np.ndarray, box: Box, axis: int, fraction: float) -> int:
    """The cell boundary along ``axis`` inside ``box`` (cells) nearest to where the load from the
    box's start reaches ``fraction`` of its load; binary search in the summed-area table
    ``summed`` (rows+1, cols+1)."""
    x0, y0, x1, y1 = box
    if axis == 0:
        loads = summed[y1, x0:x1 + 1] - summed[y0, x0:x1 + 1]
    else:
        loads = summed[y0:y1 + 1, x1] - summed[y0:y1 + 1, x0]
    loads = loads - loads[0]
    target = fraction * loads[-1]
    after = int(np.clip(np.searchsorted(loads, target), 1, len(loads) - 1))
    nearest = after - 1 if target - loads[after - 1] < loads[after] - target else after
    return box[axis] + nearest


class GridBalancer(Balancer):
    name = "grid"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "cell_px": 8, "threshold": 1.1, "memory": 0.8, "render_only": False, "min_tile_px": 16}

    def __init__(self, **params: object) -> None:
        super().__init__(**params)
        self._table: LoadTable | None = None
        self._fed: object = None

    def validate_params(self) -> None:
        if self.params["cell_px"] < 1 or self.params["min_tile_px"] < 1:
            raise ValueError("cell_px and min_tile_px must be >= 1")
        if self.params["threshold"] < 1.0:
            raise ValueError("threshold (slowest/fastest) must be >= 1")
        if not 0.0 <= self.params["memory"] < 1.0:
            raise ValueError("memory must be in [0, 1)")

    def balanced(self, inputs: BalanceInput) -> bool:
        """True when every node has a time and slowest / fastest ≤ threshold."""
        times = node_times(inputs.timings, self.params["render_only"])
        values = [times.get(node, 0.0) for node in inputs.node_ids]
        return min(values) > 0.0 and max(values) / min(values) <= self.params["threshold"]

    def partition(self, inputs: BalanceInput) -> Partition:
        minimum = minimum_for(inputs.size, len(inputs.node_ids), self.params["min_tile_px"])
        cell = max(1, min(self.params["cell_px"], minimum))
        if self._table is None or self._table.size != inputs.size or self._table.cell_px != cell:
            self._table, self._fed = LoadTable(inputs.size, cell), None
        table = self._table
        previous = inputs.previous
        matches = previous is not None and not previous.pull and inputs.previous_matches()
        if matches and inputs.timings and inputs.timings != self._fed:
            table.update(inputs.timings, inputs.weights, self.params["memory"], self.params["render_only"])
            self._fed = inputs.timings
        if previous is not None and matches and (not inputs.timings or self.balanced(inputs)):
            return previous
        summed = table.summed()
        cell_min = (math.ceil(minimum / np.diff(table.xs).min()), math.ceil(minimum / np.diff(table.ys).min()))

        def split_at(box: Box, axis: int, node: SplitNode) -> float:
            return median_cut(summed, box, axis, node.left_fraction)

        rows, cols = table.shape
        boxes = split_boxes(build_tree(inputs.node_ids, inputs.weights), (0, 0, cols, rows), cell_min, split_at)
        return to_partition(boxes, table.xs.astype(int).tolist(), table.ys.astype(int).tolist())
