"""A point cloud's points chosen for a frame within a point budget (issue 36; Potree's point budget,
from Schütz's octree renderer): the octree nodes in view, nearest and largest on screen first, until
the next would pass the budget. Pure numpy: every render node computes the same choice from the same
camera and octree, so tiles drawn on different nodes join (each tile then draws the chosen nodes
that touch it), and the coordinator predicts with it where the points of a frame will be.

Priority: a node's projected size, its subtree box's half diagonal over the distance from the eye
to the box's nearest point, in pixels (infinite with the eye inside), lowered to its parent's where
larger (a child never goes before its parent). Nodes are taken in order of that priority (ties: the
shallower first, then the lower index) among those whose box is in view (a node out of view leaves
its subtree out), as long as the running count stays within the budget: a prefix of that order, so
the choice is closed under parents — a coarse level is always drawn under its finer ones (each
level is a subsample of the one below, :mod:`node.scene.points`).

A still (no budget, :func:`still_nodes`) draws every point in view where they are at most
:data:`STILL_EVERY_POINT_MAX` (it then equals the picture of every point); beyond, every node in
view down to the level whose points lie at most :data:`STILL_SPACING_PX` apart on screen where they
lie: finer levels add points to pixels that hold several already, and with the depth test they only
choose which of them a pixel shows (a cloud far larger than a frame's pixels then costs a still what
its pixels need, not every point in view per sample). A spacing of 0 draws every point in view: the
still the coordinator refines next for a cloud of more than :data:`STILL_EVERY_POINT_MAX` points
(:mod:`tessera.scheduling.render_demand`), which ``--render-once`` makes.

Splat sizes follow the choice (:func:`refinement`): where a node's child in an octant is chosen
too, its points there are drawn at the finer spacing (one level deep; deeper, the child's coarsest).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tessera.balancers.projection import project_boxes
from tessera.geometry import Camera

#: Most points a moving frame draws (``--point-budget``). Measured on llvmpipe (bench.points, 100M
#: points, 3 nodes, 1280x720, the worst of four camera paths): 300 000 keeps a moving frame under
#: 200 ms of CPU (10 frames/s on two idle cores); 500 000 does not on the overhead path.
DEFAULT_POINT_BUDGET = 300_000
#: The smallest splat side in pixels (``--point-size``).
DEFAULT_POINT_SIZE = 2.0
#: A still draws each place down to the first level whose points lie at most this many pixels apart
#: on screen (:func:`still_nodes`). Measured (docs, benchmarks 'Point clouds', 1280x720, 4 samples): on
#: the 100M-point terrain a sample draws 5-11M of 78-85M points in view (7-16x less CPU), the still
#: 41.5-44 dB from the still of every point; on the 20M one 43-57 dB (1 px: 37-47 dB).
STILL_SPACING_PX = 0.5
#: A still draws every point in view where the nodes in view hold at most this many points
#: (:func:`still_nodes`): it then converges to the picture of every point. Measured (docs, benchmarks
#: 'Point clouds', 1280x720, llvmpipe): on a 10M-point terrain, 3-9.4M points in view, every point
#: costs a sample 0.6-1.7 s of CPU, 1-1.9 times the 0.5 px still's (43.7-58.5 dB from it); a
#: 20M-point one's 16-19M in view cost 2.4-2.8 s, up to 3.7 times; the 100M one's 78-85M, 16-18 s.
STILL_EVERY_POINT_MAX = 10_000_000
#: Most octant depths a node's refinement word holds (4 bits each).
MAX_REFINE = 15


@dataclass(frozen=True, eq=False)
class PointTree:
    """An octree of M nodes in hierarchy order (parents before children): ``boxes`` (M, 2, 3)
    float64 world boxes around each node's subtree, ``counts`` (M,) int64 its own points,
    ``parents`` (M,) int64 (−1 for the root), ``depths`` (M,) int64 and ``octants`` (M,) int64, the
    octant of its parent's cube it lies in (bit 0: x above the centre, 1: y, 2: z; 0 for the root)."""

    boxes: np.ndarray
    counts: np.ndarray
    parents: np.ndarray
    depths: np.ndarray
    octants: np.ndarray

    @property
    def node_count(self) -> int:
        return int(self.counts.shape[0])

    @property
    def point_count(self) -> int:
        return int(self.counts.sum())

    def by_depth(self) -> list[np.ndarray]:
        """Node ids of each depth 0, 1, …"""
        order = np.argsort(self.depths, kind="stable")
        bounds = np.searchsorted(self.depths[order], np.arange(int(self.depths.max(initial=0)) + 2))
        return [order[bounds[d]:bounds[d + 1]] for d in range(len(bounds) - 1)]


def pixel_scale(camera: Camera, size: tuple[int, int]) -> float:
    """Pixels per world unit at distance 1 in a ``size`` frame."""
    return size[1] / 2.0 / float(np.tan(np.radians(camera.fovy_deg) / 2.0))


def priorities(tree: PointTree, camera: Camera, size: tuple[int, int]) -> np.ndarray:
    """(M,) float64 each node's projected size in pixels, capped by its parent's (module docstring)."""
    lo, hi = tree.boxes[:, 0], tree.boxes[:, 1]
    eye = np.asarray(camera.eye, np.float64)
    distance = np.linalg.norm(np.clip(eye, lo, hi) - eye, axis=1)
    radius = np.linalg.norm(hi - lo, axis=1) / 2.0
    with np.errstate(divide="ignore"):
        raw = np.where(distance > 0.0, radius * pixel_scale(camera, size) / distance, np.inf)
    capped = raw.copy()
    for ids in tree.by_depth()[1:]:
        capped[ids] = np.minimum(raw[ids], capped[tree.parents[ids]])
    return capped


def in_view(tree: PointTree, camera: Camera, size: tuple[int, int], bounds: np.ndarray) -> np.ndarray:
    """(M,) bool: nodes whose subtree box is on screen (near/far from the scene ``bounds``), and
    whose parent is."""
    rects = project_boxes(tree.boxes.reshape(-1, 6), camera, size, bounds)
    seen = rects[:, 2] > rects[:, 0]
    for ids in tree.by_depth()[1:]:
        seen[ids] &= seen[tree.parents[ids]]
    return seen


def select_nodes(tree: PointTree, camera: Camera, size: tuple[int, int], bounds: np.ndarray,
                 budget: int | None, usable: np.ndarray | None = None) -> np.ndarray:
    """(M,) bool: the nodes a ``size`` frame seen by ``camera`` draws within ``budget`` points (None:
    every node in view), for a scene of ``bounds`` (2, 3) (near/far as every process derives them),
    among the ``usable`` ones (M,) bool (None: all; closed under parents, as a prefix of the
    hierarchy order is: a node still uploading is left out with its subtree)."""
    seen = in_view(tree, camera, size, bounds)
    if usable is not None:
        seen &= usable
    if budget is None:
        return seen
    priority = priorities(tree, camera, size)
    order = np.lexsort((np.arange(tree.node_count), tree.depths, -priority))
    order = order[seen[order]]
    taken = int(np.searchsorted(np.cumsum(tree.counts[order]), budget, side="right"))
    chosen = np.zeros(tree.node_count, bool)
    chosen[order[:taken]] = True
    return chosen


def still_nodes(tree: PointTree, camera: Camera, size: tuple[int, int], bounds: np.ndarray, spacing: float,
                usable: np.ndarray | None = None, spacing_px: float = STILL_SPACING_PX,
                every_point_max: int = STILL_EVERY_POINT_MAX) -> np.ndarray:
    """(M,) bool: the nodes a still of a ``size`` frame seen by ``camera`` draws (module docstring):
    those in view (:func:`select_nodes` with no budget), all of them where they hold at most
    ``every_point_max`` points, else those whose parent's points, ``spacing`` × 2^(1 − depth) apart
    (``spacing``: the root's, world units), lie more than ``spacing_px`` pixels apart at the node's
    subtree box's nearest point (the root always; a node with the eye in its box always); closed
    under parents."""
    chosen = select_nodes(tree, camera, size, bounds, None, usable)
    if int(tree.counts[chosen].sum()) <= every_point_max:
        return chosen
    lo, hi = tree.boxes[:, 0], tree.boxes[:, 1]
    eye = np.asarray(camera.eye, np.float64)
    distance = np.linalg.norm(np.clip(eye, lo, hi) - eye, axis=1)
    parent_spacing = spacing * np.exp2(1.0 - tree.depths) * pixel_scale(camera, size)
    chosen &= (tree.depths == 0) | (parent_spacing > spacing_px * distance)
    for ids in tree.by_depth()[1:]:
        chosen[ids] &= chosen[tree.parents[ids]]
    return chosen


def refinement(tree: PointTree, chosen: np.ndarray) -> np.ndarray:
    """(M,) uint32: for each node, 4 bits per octant c (bits 4c…4c+3): how many levels deeper than
    the node the chosen nodes reach in that octant — through its chosen child there, as deep as that
    child's shallowest octant reaches (0 where no child is chosen), at most :data:`MAX_REFINE`."""
    words = np.zeros(tree.node_count, np.uint32)
    shifts = (4 * np.arange(8)).astype(np.uint32)
    for ids in reversed(tree.by_depth()[1:]):
        ids = ids[chosen[ids]]
        reach = tree.depths[ids] + ((words[ids, None] >> shifts) & 15).min(axis=1)
        parents = tree.parents[ids]
        extra = np.clip(reach - tree.depths[parents], 0, MAX_REFINE).astype(np.uint32)
        np.bitwise_or.at(words, parents, extra << (4 * tree.octants[ids]).astype(np.uint32))
    return words


def drawn_counts(tree: PointTree, chosen: np.ndarray) -> np.ndarray:
    """(M,) int64 points each node draws with ``chosen``."""
    return np.where(chosen, tree.counts, 0)
