"""``eq-load`` — the peer baseline: Equalizer's 2D load equalizer, as its documentation describes
it (written from the description, not from its code).

A binary tree over the nodes (:mod:`tessera.balancers.support.tree`; Equalizer's "resources" are
our speed weights); each internal node cuts its region along the longer side where last frame's
load, swept across the region, reaches the left subtree's share of the region's load. The load is
the time-weighted area of last frame's tiles (each tile's time spread uniformly over its pixels:
``self.load``, :class:`~tessera.balancers.support.load.MeasuredLoad`; ``tree-predict`` gives it
the predicted field). Each cut is damped: new = ``damping`` × last frame's cut + (1 − ``damping``)
× computed (Equalizer's default 0.5; 0 = no damping, 1 = frozen), when last frame had that cut
along the same axis. Timings are busy time. Without a previous partition for these nodes and this
screen the tiles are equal (area ∝ speed weight).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

from tessera.balancers.base import BalanceInput, Balancer, Partition
from tessera.balancers.static import minimum_for
from tessera.balancers.support.load import Field, LoadField, LoadSource, MeasuredLoad
from tessera.balancers.support.tree import Box, SplitAt, SplitNode, build_tree, split_boxes, to_partition
from tessera.geometry import Rect


def _bbox(rects: list[Rect]) -> Box:
    return (min(r.x for r in rects), min(r.y for r in rects), max(r.x1 for r in rects), max(r.y1 for r in rects))


def previous_cut(rects: dict[int, Rect], node: SplitNode, axis: int) -> int | None:
    """Where last frame cut ``node``'s region along ``axis``: the left leaves' tiles and the right
    leaves' tiles must abut there and span the same extent across; None otherwise."""
    assert node.left is not None and node.right is not None
    if any(leaf not in rects for leaf in node.leaves):
        return None
    low = _bbox([rects[leaf] for leaf in node.left.leaves])
    high = _bbox([rects[leaf] for leaf in node.right.leaves])
    if low[axis + 2] != high[axis] or low[1 - axis] != high[1 - axis] or low[3 - axis] != high[3 - axis]:
        return None
    return low[axis + 2]


def damped_area_cut(field: Field, rects: dict[int, Rect], damping: float) -> SplitAt:
    """Cut where ``field``'s load swept across the region reaches the left subtree's share,
    blended with last frame's cut (from ``rects``, node id → last tile) by ``damping``."""

    def split_at(box: Box, axis: int, node: SplitNode) -> float:
        computed = field.positions(axis, (box[axis], box[axis + 2]), (box[1 - axis], box[3 - axis]),
                                   [node.left_fraction])[0]
        old = previous_cut(rects, node, axis)
        return computed if old is None else damping * old + (1.0 - damping) * computed

    return split_at


class EqLoadBalancer(Balancer):
    name = "eq-load"
    defaults: ClassVar[Mapping[str, float | int | bool]] = {"damping": 0.5, "min_tile_px": 16}

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        self.load: LoadSource = MeasuredLoad()

    def validate_params(self) -> None:
        if not 0.0 <= self.params["damping"] <= 1.0:
            raise ValueError("damping must be in [0, 1]")
        if self.params["min_tile_px"] < 1:
            raise ValueError("min_tile_px must be >= 1")

    def partition(self, inputs: BalanceInput) -> Partition:
        width, height = inputs.size
        tree = build_tree(inputs.node_ids, inputs.weights)
        minimum = minimum_for(inputs.size, len(inputs.node_ids), self.params["min_tile_px"])
        previous = inputs.previous
        matches = previous is not None and not previous.pull and inputs.previous_matches()
        if previous is not None and matches and not inputs.timings:
            return previous
        field = self.load.field(inputs) if matches else LoadField.uniform(inputs.size)
        rects = {t.node_id: t.rect for t in previous.tiles if t.node_id is not None} if previous and matches else {}
        split_at = damped_area_cut(field, rects, self.params["damping"])
        return to_partition(split_boxes(tree, (0, 0, width, height), (minimum, minimum), split_at))
