"""Binary split trees of nodes, shared by ``eq-load``, ``grid`` and ``hetero`` (pure).

The tree is seed 003 §2's performance tree (and Equalizer's split tree, and seed 002's k:(N−k)
median cut): leaves are the nodes in id order weighted by speed, the left subtree holds the first
⌈n/2⌉, a parent weighs the sum of its children. Each internal node cuts its region in two along
the region's longer side; the technique only chooses where (``split_at``); this module keeps every
leaf at least the minimum tile size and the result an exact cover.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from tessera.balancers.base import Partition, Tile
from tessera.balancers.support.load import speed_of
from tessera.geometry import Rect

#: x0, y0, x1, y1 in whole units (pixels, or grid cells)
Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class SplitNode:
    """A subtree: its leaves (node ids), their summed speed weight, and its two children."""

    leaves: tuple[int, ...]
    weight: float
    left: SplitNode | None = None
    right: SplitNode | None = None

    @property
    def left_fraction(self) -> float:
        """Share of the region's load the left child gets: weight(left) / weight(self)."""
        assert self.left is not None
        return self.left.weight / self.weight


def build_tree(node_ids: Sequence[int], weights: Mapping[int, float]) -> SplitNode:
    """The tree over ``node_ids`` (sorted), leaves weighted by ``weights`` (missing = 1)."""
    nodes = sorted(node_ids)
    if not nodes:
        raise ValueError("need at least one node")
    if len(nodes) == 1:
        return SplitNode((nodes[0],), speed_of(weights, nodes[0]))
    half = (len(nodes) + 1) // 2
    left, right = build_tree(nodes[:half], weights), build_tree(nodes[half:], weights)
    return SplitNode(tuple(nodes), left.weight + right.weight, left, right)


#: (region, axis 0 = x / 1 = y, tree node) → wanted cut position along the axis, in units
SplitAt = Callable[[Box, int, SplitNode], float]


def _bounds(box: Box, axis: int, node: SplitNode, minimum: tuple[int, int]) -> tuple[int, int] | None:
    """Lowest and highest cut along ``axis`` leaving each child room for its leaves, or None."""
    start, end = box[axis], box[axis + 2]
    across = box[3 - axis] - box[1 - axis]
    per_line = max(1, across // minimum[1 - axis])
    assert node.left is not None and node.right is not None
    low = start + math.ceil(len(node.left.leaves) / per_line) * minimum[axis]
    high = end - math.ceil(len(node.right.leaves) / per_line) * minimum[axis]
    return (low, high) if low <= high else None


def split_boxes(tree: SplitNode, box: Box, minimum: tuple[int, int], split_at: SplitAt) -> dict[int, Box]:
    """Leaf node id → its box, recursively cutting ``box``; ``minimum`` = (x, y) tile size in units.

    Where the preferred (longer) side cannot hold both children at the minimum size the other
    side is tried, then a minimum of one unit; ValueError if the region cannot hold its leaves.
    """
    if tree.left is None or tree.right is None:
        return {tree.leaves[0]: box}
    width, height = box[2] - box[0], box[3] - box[1]
    preferred = 0 if width >= height else 1
    for size in (minimum, (1, 1)):
        for axis in (preferred, 1 - preferred):
            bounds = _bounds(box, axis, tree, size)
            if bounds is not None:
                cut = min(max(round(split_at(box, axis, tree)), bounds[0]), bounds[1])
                low: Box = (box[0], box[1], cut, box[3]) if axis == 0 else (box[0], box[1], box[2], cut)
                high: Box = (cut, box[1], box[2], box[3]) if axis == 0 else (box[0], cut, box[2], box[3])
                return {**split_boxes(tree.left, low, minimum, split_at),
                        **split_boxes(tree.right, high, minimum, split_at)}
    raise ValueError(f"a {width}x{height} region cannot hold {len(tree.leaves)} tiles")


def to_partition(boxes: Mapping[int, Box], xs: Sequence[int] | None = None,
                 ys: Sequence[int] | None = None) -> Partition:
    """One tile per node (id order); box units map to pixels through the edge lists ``xs``, ``ys``
    (cell k spans xs[k]..xs[k+1]) when given, else they are pixels."""
    tiles = []
    for node, (x0, y0, x1, y1) in sorted(boxes.items()):
        if xs is not None and ys is not None:
            x0, x1, y0, y1 = int(xs[x0]), int(xs[x1]), int(ys[y0]), int(ys[y1])
        tiles.append(Tile(Rect(x0, y0, x1 - x0, y1 - y0), node))
    return Partition(tuple(tiles))
