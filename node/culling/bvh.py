"""The tree over a scene's chunks and its CPU traversal (seed 001, the CPU side of ch. 6; seed 002
§3.4 for why chunks exist): a bounding-volume tree over chunk boxes, tested against a tile's
sub-frustum (:mod:`node.culling.frustum`), and the visible chunks coalesced into as few ranges as
possible.

The tree is built over chunks in their given order (octree depth-first order from
:func:`node.scene.octree.octree_split`) by halving the chunk range, so every tree node covers a
contiguous range of chunks, hence of faces: a node wholly inside the tile is one draw range.

The traversal is vectorised (:func:`cull`): the frontier of nodes is tested at once with the
p-/n-vertex box–plane test, :data:`LEVEL_STEP` tree levels per step, because the number of numpy
calls is what a tile's cull costs (docs/explanation/culling.md). Plane masking and plane coherency (testing
first the plane that culled a node last frame) only pay in a one-node-at-a-time loop and are left
out.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

#: The CPU traversal tests the binary tree this many levels at a time (a 2⁵ = 32-ary view of it):
#: the fastest of 2…7 measured (docs/explanation/culling.md).
LEVEL_STEP = 5


@dataclass(frozen=True, slots=True)
class ChunkBVH:
    """Binary bounding-volume tree over C chunks, N = 2C − 1 nodes in breadth-first order, root 0.

    ``lo``/``hi`` (N, 3) float64 node boxes, ``center``/``extent`` (N, 3) the same as centre and
    half size; ``left``/``right`` (N,) int32 children (right = left + 1; −1 at a leaf);
    ``parent`` (N,) int32 (−1 at the root); ``first_chunk``/``end_chunk`` (N,) int32: the node
    covers chunks [first_chunk, end_chunk); a leaf covers exactly one chunk; ``depth`` (N,) int64
    (0 at the root).

    For the CPU traversal: ``center_t``/``extent_t`` (3, N) float64, the boxes transposed;
    ``cuts``: node ids (n_i,) int64 of the tree's cuts at depths 0, :data:`LEVEL_STEP`,
    2·LEVEL_STEP, …, and finally all leaves (a cut at depth D holds the nodes at depth D and the
    leaves above it), each sorted by first chunk; ``cut_children``: for each cut but the last,
    (lo, hi) (n_i,) int64: a node's descendants in the next cut are that cut's entries [lo, hi).
    """

    lo: np.ndarray
    hi: np.ndarray
    center: np.ndarray
    extent: np.ndarray
    left: np.ndarray
    right: np.ndarray
    parent: np.ndarray
    first_chunk: np.ndarray
    end_chunk: np.ndarray
    depth: np.ndarray
    center_t: np.ndarray
    extent_t: np.ndarray
    cuts: tuple[np.ndarray, ...]
    cut_children: tuple[tuple[np.ndarray, np.ndarray], ...]

    @property
    def node_count(self) -> int:
        return int(self.left.size)

    @property
    def chunk_count(self) -> int:
        return int(self.end_chunk[0])

    @property
    def is_leaf(self) -> np.ndarray:
        return self.left < 0


def build_chunk_bvh(chunk_bounds: np.ndarray, level_step: int = LEVEL_STEP) -> ChunkBVH:
    """Tree over chunk boxes ``chunk_bounds`` (C, 2, 3), splitting each chunk range at its middle."""
    boxes = np.asarray(chunk_bounds, dtype=np.float64)
    chunk_total = boxes.shape[0]
    if chunk_total == 0:
        raise ValueError("cannot build a BVH over zero chunks")
    level_first, level_end = [np.array([0])], [np.array([chunk_total])]
    while True:
        first, end = level_first[-1], level_end[-1]
        split = end - first > 1
        if not split.any():
            break
        mid = (first[split] + end[split]) // 2
        level_first.append(np.stack([first[split], mid], axis=1).ravel())
        level_end.append(np.stack([mid, end[split]], axis=1).ravel())
    offsets = np.cumsum([0] + [f.size for f in level_first])
    first_chunk = np.concatenate(level_first).astype(np.int32)
    end_chunk = np.concatenate(level_end).astype(np.int32)
    node_total = int(offsets[-1])
    left = np.full(node_total, -1, np.int32)
    parent = np.full(node_total, -1, np.int32)
    for level in range(len(level_first) - 1):
        inner = offsets[level] + np.flatnonzero(level_end[level] - level_first[level] > 1)
        children = offsets[level + 1] + 2 * np.arange(inner.size)
        left[inner] = children
        parent[children] = parent[children + 1] = inner
    right = np.where(left >= 0, left + 1, -1).astype(np.int32)
    lo = np.empty((node_total, 3))
    hi = np.empty((node_total, 3))
    for level in reversed(range(len(level_first))):  # children before parents
        nodes = np.arange(offsets[level], offsets[level + 1])
        leaf = left[nodes] < 0
        lo[nodes[leaf]] = boxes[first_chunk[nodes[leaf]], 0]
        hi[nodes[leaf]] = boxes[first_chunk[nodes[leaf]], 1]
        inner = nodes[~leaf]
        lo[inner] = np.minimum(lo[left[inner]], lo[right[inner]])
        hi[inner] = np.maximum(hi[left[inner]], hi[right[inner]])
    center, extent = (lo + hi) * 0.5, (hi - lo) * 0.5
    depth = np.repeat(np.arange(offsets.size - 1), np.diff(offsets))
    cuts, cut_children = _cuts(depth, left, first_chunk, end_chunk, level_step)
    return ChunkBVH(lo, hi, center, extent, left, right, parent, first_chunk, end_chunk, depth,
                    np.ascontiguousarray(center.T), np.ascontiguousarray(extent.T), cuts, cut_children)


def _cuts(depth: np.ndarray, left: np.ndarray, first_chunk: np.ndarray, end_chunk: np.ndarray,
          level_step: int) -> tuple[tuple[np.ndarray, ...], tuple[tuple[np.ndarray, np.ndarray], ...]]:
    """The cuts of :class:`ChunkBVH` every ``level_step`` levels, and each cut's child ranges."""
    if level_step < 1:
        raise ValueError(f"level_step must be ≥ 1, got {level_step}")
    deepest = int(depth[-1])
    cuts = []
    for cut_depth in [*range(0, deepest, level_step), deepest]:
        nodes = np.flatnonzero((depth == cut_depth) | ((depth < cut_depth) & (left < 0)))
        cuts.append(nodes[np.argsort(first_chunk[nodes], kind="stable")].astype(np.int64))
    children = []
    for upper, lower in itertools.pairwise(cuts):
        lower_first = first_chunk[lower]
        children.append((np.searchsorted(lower_first, first_chunk[upper]).astype(np.int64),
                         np.searchsorted(lower_first, end_chunk[upper]).astype(np.int64)))
    return tuple(cuts), tuple(children)


@dataclass(frozen=True, slots=True)
class CullResult:
    """What one tile's cull found.

    ``visible_first``/``visible_end`` (R,) int64: the kept chunks as sorted, disjoint, non-touching
    ranges [first, end) (a node wholly inside the tile is one range); ``terminal_nodes`` (T,) int64:
    the nodes where the traversal stopped (culled, wholly inside, or leaves) — they cover every
    chunk once and seed the GPU's temporal-coherence input (seed 001 §6.1.2); ``nodes_visited``:
    nodes tested; ``chunks_tested``: leaves tested.
    """

    visible_first: np.ndarray
    visible_end: np.ndarray
    terminal_nodes: np.ndarray
    nodes_visited: int
    chunks_tested: int

    @property
    def visible_chunks(self) -> np.ndarray:
        """(K,) int64 sorted ids of the kept chunks."""
        return range_members(self.visible_first, self.visible_end)

    @property
    def visible_count(self) -> int:
        return int((self.visible_end - self.visible_first).sum())


def cull(bvh: ChunkBVH, planes: np.ndarray, hidden: tuple[np.ndarray, np.ndarray] | None = None) -> CullResult:
    """Chunks of ``bvh`` whose boxes are not wholly outside one of ``planes`` (6, 4), but those
    in ``hidden``: (first, end) (J,) int64 sorted disjoint chunk ranges nothing of which is drawn
    (what a frame's coarse levels stand in for), whose subtrees are skipped as culled ones are
    (a subtree within one range: merge touching ranges to skip more). The traversal of a tile
    drawn at coarse levels then stops where the levels begin (a narrow strip of the 24.8M model
    drawn at 1.5 px walked 20 ms of tree for chunks it left out).

    Top-down over ``bvh.cuts``: each step tests the whole frontier at once (p-/n-vertex test in
    centre/extent form); culled nodes, nodes wholly inside every plane and leaves stop; the others
    are replaced by their descendants :data:`LEVEL_STEP` levels down. Stepping several levels at a
    time keeps the number of numpy calls small (the cost that dominates here); subtrees outside the
    tile are still skipped after one test. Plane masking (not re-testing planes a parent lies wholly
    inside) saves nothing in a vectorised test; by box containment it changes no result.
    """
    planes = np.asarray(planes, dtype=np.float64)
    normals, offsets, abs_normals = planes[:, :3], planes[:, 3:], np.abs(planes[:, :3])
    frontier = np.zeros(1, np.int64)                      # positions in the current cut
    kept_first, kept_end, terminal = [], [], []
    nodes_visited = chunks_tested = 0
    for level, cut in enumerate(bvh.cuts):
        nodes = cut[frontier]
        distance = normals @ np.take(bvh.center_t, nodes, axis=1) + offsets      # (6, n)
        radius = abs_normals @ np.take(bvh.extent_t, nodes, axis=1)
        outside = (distance < -radius).any(axis=0)
        if hidden is not None:
            outside |= _within(hidden, bvh.first_chunk[nodes], bvh.end_chunk[nodes])
        leaf = bvh.left[nodes] < 0
        stop = outside | leaf | (distance >= radius).all(axis=0)
        kept = nodes[stop & ~outside]
        kept_first.append(bvh.first_chunk[kept])
        kept_end.append(bvh.end_chunk[kept])
        terminal.append(nodes[stop])
        nodes_visited += nodes.size
        chunks_tested += int(np.count_nonzero(leaf))
        if stop.all():
            break
        child_lo, child_hi = bvh.cut_children[level]
        frontier = range_members(child_lo[frontier[~stop]], child_hi[frontier[~stop]])
    first, end = merge_touching(np.concatenate(kept_first), np.concatenate(kept_end))
    return CullResult(first, end, np.concatenate(terminal), nodes_visited, chunks_tested)


def _within(ranges: tuple[np.ndarray, np.ndarray], first: np.ndarray, end: np.ndarray) -> np.ndarray:
    """(n,) bool: whether each range [first, end) lies within one of the sorted disjoint ``ranges``."""
    starts, ends = ranges
    if starts.size == 0:
        return np.zeros(first.shape, bool)
    i = np.searchsorted(starts, first, side="right") - 1
    return (i >= 0) & (ends[np.maximum(i, 0)] >= end)


def merge_touching(first: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Disjoint ranges [first, end) (R,) → sorted (int64), touching ones merged."""
    order = np.argsort(first)
    first, end = first[order].astype(np.int64), end[order].astype(np.int64)
    if first.size == 0:
        return first, end
    head = np.flatnonzero(np.concatenate(([True], first[1:] != end[:-1])))
    return first[head], end[np.append(head[1:], first.size) - 1]


def covering_nodes(bvh: ChunkBVH, first: np.ndarray, end: np.ndarray, most: int) -> np.ndarray:
    """(K,) int64 the nodes of ``bvh``'s deepest cut of at most ``most`` nodes (``bvh.cuts``) that hold
    a chunk of the sorted disjoint ranges [first, end) (R,): their boxes hold those chunks' boxes,
    ``most`` boxes at most however many chunks (the root's cut always fits)."""
    cut = next(nodes for nodes in reversed(bvh.cuts) if nodes.size <= most)
    if first.size == 0:
        return cut[:0]
    # A node [a, b) holds a chunk of the ranges where the first range ending after a starts before b.
    after = np.searchsorted(end, bvh.first_chunk[cut], side="right")
    holds = (after < first.size) & (first[np.minimum(after, first.size - 1)] < bvh.end_chunk[cut])
    return cut[holds]


def range_members(first: np.ndarray, end: np.ndarray) -> np.ndarray:
    """(K,) int64 every integer of the ranges [first[i], end[i]) (M,), concatenated in order."""
    first = np.asarray(first, dtype=np.int64)
    counts = np.asarray(end, dtype=np.int64) - first
    return np.repeat(first - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))


def bvh_arrays(bvh: ChunkBVH) -> dict[str, np.ndarray]:
    """The arrays that :func:`bvh_from_arrays` makes ``bvh`` again from (a scene cache entry keeps
    them, so that opening it builds no tree): every field but ``center``/``extent`` (views of the
    transposed ones), the cuts as ``cut-i`` and their child ranges as ``cut_lo-i``/``cut_hi-i``."""
    arrays = {name: getattr(bvh, name) for name in ("lo", "hi", "left", "right", "parent", "first_chunk",
                                                    "end_chunk", "depth", "center_t", "extent_t")}
    arrays.update({f"cut-{i}": cut for i, cut in enumerate(bvh.cuts)})
    for i, (lo, hi) in enumerate(bvh.cut_children):
        arrays[f"cut_lo-{i}"], arrays[f"cut_hi-{i}"] = lo, hi
    return arrays


def bvh_from_arrays(arrays: Mapping[str, np.ndarray]) -> ChunkBVH:
    """The tree :func:`bvh_arrays` gave ``arrays`` of (they are used as they are: memory maps stay
    maps). Raises KeyError when one is missing, ValueError when their shapes disagree."""
    center_t, extent_t = arrays["center_t"], arrays["extent_t"]
    cut_count = sum(name.startswith("cut-") for name in arrays)
    bvh = ChunkBVH(arrays["lo"], arrays["hi"], center_t.T, extent_t.T, arrays["left"], arrays["right"],
                   arrays["parent"], arrays["first_chunk"], arrays["end_chunk"], arrays["depth"], center_t, extent_t,
                   tuple(arrays[f"cut-{i}"] for i in range(cut_count)),
                   tuple((arrays[f"cut_lo-{i}"], arrays[f"cut_hi-{i}"]) for i in range(cut_count - 1)))
    nodes = bvh.node_count
    if any(a.shape != (nodes, 3) for a in (bvh.lo, bvh.hi, bvh.center, bvh.extent)) or \
            any(a.shape != (nodes,) for a in (bvh.right, bvh.parent, bvh.first_chunk, bvh.end_chunk, bvh.depth)) or \
            not bvh.cuts or nodes != 2 * bvh.chunk_count - 1:
        raise ValueError(f"the tree's arrays disagree on its {nodes} nodes")
    return bvh
