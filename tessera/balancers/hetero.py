"""``hetero`` — seed 003: sort-first balancing for heterogeneous nodes (performance tree + DPBP).

1. Calibration (pure part): every node renders the same central region (:func:`calibration_region`)
   when it joins or on demand; :func:`calibration_weights` turns the times tᵢ into Pᵢ = t_max / tᵢ,
   which the coordinator passes in ``BalanceInput.weights``.
2. Performance binary tree (:func:`tessera.balancers.support.tree.build_tree`): leaves weighted
   Pᵢ, a parent the sum; at each internal node M = weight(left) / weight(right) is the split ratio.
3. DPBP: ``BalanceInput.groups`` holds the primitive groups' boxes projected and clipped to the
   screen, weighted by primitive count. 4. Sweep (:func:`dpbp_cut`): a line sweeps the region; a
   box enters list A when the line reaches its start and leaves list B at its end; at each box end
   K = weight(A) / weight(B); the region is cut at the first end where K ≥ M. The patent sweeps
   left to right; we sweep along the region's longer side (squarish tiles, seed 000 §4.2). A region
   holding no box end that reaches M — or no groups given — is cut by last frame's time-weighted
   area instead, damped by ``damping`` (``eq-load``'s cut), or by area before any timing.
5. Trigger: Δt = Σ|tᵢ − mean(t)|; the partition is kept while Δt < Δt_max, Δt_max =
   ``dt_max_ratio`` × mean(t) (the patent's Δt_max is absolute; relative to the mean it holds
   across scenes: 0.1 re-partitions once one node runs 5 % over the mean, whatever N). A node
   change, a new calibration or a node without a time re-partitions.

Weight refinement: the cut gives node i a share of the load ∝ the weight wᵢ used, so its time
tᵢ ∝ wᵢ / (true speed); after every measured frame each weight moves ``refine_gain`` of the way
toward wᵢ / tᵢ (rescaled to the same total), which is the true speed in one step when the load
estimate is right, and otherwise also absorbs what the primitive counts miss (fill-rate cost).
(Without groups the time field already carries each node's speed — effort = time × weight — so
there the refinement settles wherever times balance.) A new calibration of a node restarts its
weight from Pᵢ. Timings are busy time by default (``render_only`` = True: render time alone, the
patent's literal "render time").
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np

from tessera.balancers.base import BalanceInput, Balancer, Partition, ProjectedGroups
from tessera.balancers.eq_load import damped_area_cut
from tessera.balancers.static import minimum_for
from tessera.balancers.support.load import LoadField, node_times, speed_of
from tessera.balancers.support.tree import Box, SplitNode, build_tree, split_boxes, to_partition
from tessera.geometry import Rect


def calibration_region(size: tuple[int, int]) -> Rect:
    """The central region A every node renders for calibration: the middle half in each direction."""
    width, height = size
    return Rect(width // 4, height // 4, max(width // 2, 1), max(height // 2, 1))


def calibration_weights(times_ms: Mapping[int, float]) -> dict[int, float]:
    """Pᵢ = t_max / tᵢ from each node's calibration render time (ms); the slowest node gets 1.
    Nodes without a finite positive time get no weight (balancers then count them as 1)."""
    valid = {node: t for node, t in times_ms.items() if np.isfinite(t) and t > 0.0}
    slowest = max(valid.values(), default=0.0)
    return {node: slowest / t for node, t in valid.items()}


def dpbp_cut(groups: ProjectedGroups, box: Box, axis: int, ratio: float) -> float | None:
    """Seed 003 step 4 inside ``box`` (pixels): the first box end c along ``axis`` where
    weight(boxes starting before c) / weight(boxes ending after c) ≥ ``ratio``; None if none.
    Boxes are those of ``groups`` overlapping ``box``, with their whole primitive count."""
    b, w = np.asarray(groups.boxes, dtype=np.float64).reshape(-1, 4), np.asarray(groups.weights, dtype=np.float64)
    inside = (b[:, 0] < box[2]) & (b[:, 2] > box[0]) & (b[:, 1] < box[3]) & (b[:, 3] > box[1]) & (w > 0.0)
    starts, ends, w = b[inside, axis], b[inside, axis + 2], w[inside]
    candidates = np.unique(ends[(ends > box[axis]) & (ends < box[axis + 2])])
    if candidates.size == 0:
        return None
    order = np.argsort(starts)
    started = np.concatenate([[0.0], np.cumsum(w[order])])[np.searchsorted(starts[order], candidates, side="left")]
    order = np.argsort(ends)
    finished = np.concatenate([[0.0], np.cumsum(w[order])])[np.searchsorted(ends[order], candidates, side="right")]
    unfinished = w.sum() - finished
    reached = started >= ratio * unfinished
    return float(candidates[np.argmax(reached)]) if reached.any() else None


class HeteroBalancer(Balancer):
    name = "hetero"
    uses_groups = True
    defaults: ClassVar[Mapping[str, float | int | bool]] = {
        "dt_max_ratio": 0.1, "refine_gain": 0.5, "damping": 0.5, "render_only": False, "min_tile_px": 16}

    def __init__(self, **params: object) -> None:
        super().__init__(**params)
        self._calibrated: dict[int, float] = {}
        self._refined: dict[int, float] = {}
        self._used: dict[int, float] = {}
        self._fed: object = None

    def validate_params(self) -> None:
        if self.params["dt_max_ratio"] < 0.0:
            raise ValueError("dt_max_ratio must be >= 0")
        if not 0.0 <= self.params["refine_gain"] <= 1.0:
            raise ValueError("refine_gain must be in [0, 1]")
        if not 0.0 <= self.params["damping"] <= 1.0:
            raise ValueError("damping must be in [0, 1]")
        if self.params["min_tile_px"] < 1:
            raise ValueError("min_tile_px must be >= 1")

    @property
    def weights(self) -> dict[int, float]:
        """The refined speed weights (node id → weight)."""
        return dict(self._refined)

    def _recalibrate(self, inputs: BalanceInput) -> bool:
        """Take new calibration weights; True if any node's changed (or nodes changed)."""
        calibrated = {node: speed_of(inputs.weights, node) for node in inputs.node_ids}
        changed = calibrated != self._calibrated
        self._refined = {node: self._refined[node] if self._calibrated.get(node) == p and node in self._refined
                         else p for node, p in calibrated.items()}
        self._calibrated = calibrated
        return changed

    def _refine(self, times: dict[int, float]) -> None:
        """Move each weight toward used weight / measured time (same total)."""
        if set(self._used) != set(times):
            return
        target = {node: self._used[node] / times[node] for node in times}
        scale = sum(self._refined.values()) / sum(target.values())
        gain = self.params["refine_gain"]
        self._refined = {node: (1.0 - gain) * w + gain * target[node] * scale for node, w in self._refined.items()}

    def partition(self, inputs: BalanceInput) -> Partition:
        changed = self._recalibrate(inputs)
        previous = inputs.previous
        matches = previous is not None and not previous.pull and inputs.previous_matches()
        times = node_times(inputs.timings, self.params["render_only"])
        times = {node: times.get(node, 0.0) for node in inputs.node_ids}
        measured = matches and min(times.values()) > 0.0
        if measured and inputs.timings != self._fed:
            self._refine(times)
            self._fed = inputs.timings
        mean = sum(times.values()) / len(times)
        spread = sum(abs(t - mean) for t in times.values())
        if previous is not None and matches and not changed and (
                not inputs.timings or (measured and spread < self.params["dt_max_ratio"] * mean)):
            return previous
        return self._cut(inputs, measured)

    def _cut(self, inputs: BalanceInput, measured: bool) -> Partition:
        width, height = inputs.size
        minimum = minimum_for(inputs.size, len(inputs.node_ids), self.params["min_tile_px"])
        field = LoadField.from_timings(inputs.size, inputs.timings, self._refined) if measured \
            else LoadField.uniform(inputs.size)
        rects = {t.node_id: t.rect for t in inputs.previous.tiles if t.node_id is not None} \
            if inputs.previous and measured else {}
        area_cut = damped_area_cut(field, rects, self.params["damping"])
        groups = inputs.groups

        def split_at(box: Box, axis: int, node: SplitNode) -> float:
            assert node.left is not None and node.right is not None
            cut = dpbp_cut(groups, box, axis, node.left.weight / node.right.weight) if groups else None
            return area_cut(box, axis, node) if cut is None else cut

        self._used = dict(self._refined)
        return to_partition(split_boxes(build_tree(inputs.node_ids, self._refined), (0, 0, width, height),
                                        (minimum, minimum), split_at))
