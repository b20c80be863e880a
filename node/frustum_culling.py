"""Per-tile hierarchical frustum culling on the CPU (seed 001, the CPU side of ch. 6; seed 002 §3.4
for why chunks exist): a bounding-volume tree over chunk boxes, tested against the tile's
sub-frustum, and the visible chunks coalesced into as few draw ranges as possible.

The tree is built over chunks in their given order (octree depth-first order from
:func:`node.octree_split.octree_split`) by halving the chunk range, so every tree node covers a
contiguous range of chunks, hence of faces: a node wholly inside the tile is one draw range.

The traversal is level-synchronous and vectorised: each level's frontier of nodes is tested at
once with the p-/n-vertex box–plane test (in centre/extent form). Plane masking is kept per node:
planes a parent lies wholly inside are not consulted for its children. Plane coherency (testing
first the plane that culled a node last frame) only pays in a one-node-at-a-time loop and is left out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tessera.geometry import Camera, Rect, view_projection

#: Tile planes are pushed outward by this many pixels, so a chunk touching the tile is never culled.
DEFAULT_PAD_PX = 1.0
#: Near/far planes are pushed outward by this much NDC depth (float32 rounding in GL and on the GPU).
DEPTH_SLACK = 1e-5


def frustum_planes_from_matrix(view_proj: np.ndarray, size: tuple[int, int], rect: Rect,
                               pad_px: float = DEFAULT_PAD_PX) -> np.ndarray:
    """(6, 4) float64 world-space planes (a, b, c, d), inside where a·x + b·y + c·z + d ≥ 0, of the
    sub-frustum of full-frame ``view_proj`` (4×4 world→clip) that ``rect`` covers in a ``size`` =
    (width, height) image, pushed outward by ``pad_px`` pixels and :data:`DEPTH_SLACK`, so culling
    stays conservative. Order: left, right, bottom, top, near, far; normals are unit length."""
    width, height = size
    m = np.asarray(view_proj, dtype=np.float64)
    x0 = 2.0 * (rect.x - pad_px) / width - 1.0
    x1 = 2.0 * (rect.x1 + pad_px) / width - 1.0
    y0 = 1.0 - 2.0 * (rect.y1 + pad_px) / height      # pixel rows count down from the top
    y1 = 1.0 - 2.0 * (rect.y - pad_px) / height
    planes = np.stack([m[0] - x0 * m[3], x1 * m[3] - m[0],
                       m[1] - y0 * m[3], y1 * m[3] - m[1],
                       m[2] + (1.0 + DEPTH_SLACK) * m[3], (1.0 + DEPTH_SLACK) * m[3] - m[2]])
    return planes / np.linalg.norm(planes[:, :3], axis=1, keepdims=True)


def tile_frustum_planes(camera: Camera, size: tuple[int, int], rect: Rect, bounds: np.ndarray,
                        pad_px: float = DEFAULT_PAD_PX) -> np.ndarray:
    """(6, 4) float64 world-space planes of ``rect``'s sub-frustum, from the same
    :func:`view_projection` (near/far from the scene ``bounds`` (2, 3)) that the renderer draws
    with. A renderer that already holds the frame's matrix calls :func:`frustum_planes_from_matrix`."""
    return frustum_planes_from_matrix(view_projection(camera, size, bounds), size, rect, pad_px)


@dataclass(frozen=True, slots=True)
class ChunkBVH:
    """Binary bounding-volume tree over C chunks, N = 2C − 1 nodes in breadth-first order, root 0.

    ``lo``/``hi`` (N, 3) float64 node boxes, ``center``/``extent`` (N, 3) the same as centre and
    half size; ``left``/``right`` (N,) int32 children (right = left + 1; −1 at a leaf);
    ``parent`` (N,) int32 (−1 at the root); ``first_chunk``/``end_chunk`` (N,) int32: the node
    covers chunks [first_chunk, end_chunk); a leaf covers exactly one chunk.
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

    @property
    def node_count(self) -> int:
        return int(self.left.size)

    @property
    def chunk_count(self) -> int:
        return int(self.end_chunk[0])

    @property
    def is_leaf(self) -> np.ndarray:
        return self.left < 0


def build_chunk_bvh(chunk_bounds: np.ndarray) -> ChunkBVH:
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
    return ChunkBVH(lo, hi, (lo + hi) * 0.5, (hi - lo) * 0.5, left, right, parent, first_chunk, end_chunk)


def classify_boxes(lo: np.ndarray, hi: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For boxes ``lo``/``hi`` (K, 3) and ``planes`` (P, 4): (outside, inside) (K, P) bool — the box
    lies wholly on the negative side (p-vertex test), or wholly on the positive side (n-vertex)."""
    center = (lo + hi) * 0.5
    extent = (hi - lo) * 0.5
    distance = center @ planes[:, :3].T + planes[:, 3]
    radius = extent @ np.abs(planes[:, :3]).T
    return distance + radius < 0.0, distance - radius >= 0.0


@dataclass(frozen=True, slots=True)
class CullResult:
    """What one tile's cull found.

    ``visible_chunks`` (K,) int64 sorted chunk ids; ``terminal_nodes`` (T,) int32: the nodes where
    the traversal stopped (culled, wholly inside, or visible leaves) — they cover every chunk once
    and seed the GPU's temporal-coherence input (seed 001 §6.1.2); ``nodes_visited``: nodes tested;
    ``chunks_tested``: leaves tested.
    """

    visible_chunks: np.ndarray
    terminal_nodes: np.ndarray
    nodes_visited: int
    chunks_tested: int


def cull(bvh: ChunkBVH, planes: np.ndarray) -> CullResult:
    """Chunks of ``bvh`` whose boxes are not wholly outside one of ``planes`` (6, 4)."""
    planes = np.asarray(planes, dtype=np.float64)
    normals_t, offsets, abs_normals_t = planes[:, :3].T, planes[:, 3], np.abs(planes[:, :3]).T
    frontier = np.zeros(1, np.int32)
    active = np.ones((1, planes.shape[0]), bool)
    visible_first, visible_end, terminal = [], [], []
    nodes_visited = chunks_tested = 0
    while frontier.size:
        nodes_visited += frontier.size
        left = bvh.left[frontier]
        chunks_tested += int(np.count_nonzero(left < 0))
        distance = bvh.center[frontier] @ normals_t + offsets
        radius = bvh.extent[frontier] @ abs_normals_t
        culled = ((distance < -radius) & active).any(axis=1)
        active &= distance < radius                      # drop planes the box lies wholly inside
        emit = ~culled & ((left < 0) | ~active.any(axis=1))
        stop = culled | emit
        visible_first.append(bvh.first_chunk[frontier[emit]])
        visible_end.append(bvh.end_chunk[frontier[emit]])
        terminal.append(frontier[stop])
        frontier = (left[~stop, None] + np.array([0, 1], np.int32)).ravel()
        active = np.repeat(active[~stop], 2, axis=0)
    visible = np.sort(range_members(np.concatenate(visible_first), np.concatenate(visible_end)))
    return CullResult(visible, np.concatenate(terminal), nodes_visited, chunks_tested)


def cull_flat(bvh: ChunkBVH, planes: np.ndarray) -> np.ndarray:
    """(K,) int64 sorted chunks kept by testing every leaf box against ``planes`` (6, 4) at once —
    the same set as :func:`cull`, without the hierarchy: in numpy, one matrix product beats a
    level-by-level walk while chunks number in the hundreds or thousands."""
    leaves = np.flatnonzero(bvh.left < 0)
    outside, _ = classify_boxes(bvh.lo[leaves], bvh.hi[leaves], np.asarray(planes, dtype=np.float64))
    return np.sort(bvh.first_chunk[leaves[~outside.any(axis=1)]]).astype(np.int64)


def range_members(first: np.ndarray, end: np.ndarray) -> np.ndarray:
    """(K,) int64 every integer of the ranges [first[i], end[i]) (M,), concatenated in order."""
    first = np.asarray(first, dtype=np.int64)
    counts = np.asarray(end, dtype=np.int64) - first
    return np.repeat(first - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))


def merge_ranges(visible_chunks: np.ndarray, chunk_starts: np.ndarray,
                 chunk_ends: np.ndarray) -> list[tuple[int, int]]:
    """Fewest (start, count) ranges covering the ``visible_chunks`` (K,) ids, given each chunk's
    [start, end) (C,) — in faces or indices, the ranges come out in the same unit. Chunks whose
    ranges touch are merged into one draw."""
    chunks = np.unique(np.asarray(visible_chunks, dtype=np.int64))
    if chunks.size == 0:
        return []
    starts = np.asarray(chunk_starts, dtype=np.int64)[chunks]
    ends = np.asarray(chunk_ends, dtype=np.int64)[chunks]
    run_first = np.flatnonzero(np.concatenate(([True], starts[1:] != ends[:-1])))
    run_last = np.append(run_first[1:], chunks.size) - 1
    return [(int(s), int(e - s)) for s, e in zip(starts[run_first], ends[run_last], strict=True)]


def indirect_commands(ranges: list[tuple[int, int]] | np.ndarray, base_vertex: int = 0) -> np.ndarray:
    """(N, 5) uint32 DrawElementsIndirectCommand rows (count, instanceCount, firstIndex, baseVertex,
    baseInstance) for index ``ranges`` (start, count), one instance each: upload and draw them all
    with one ``VertexArray.render_indirect(buffer, count=N)`` (glMultiDrawElementsIndirect)."""
    spans = np.asarray(ranges, dtype=np.int64).reshape(-1, 2)
    commands = np.zeros((spans.shape[0], 5), np.uint32)
    commands[:, 0] = spans[:, 1]
    commands[:, 1] = 1
    commands[:, 2] = spans[:, 0]
    commands[:, 3] = base_vertex
    return commands
