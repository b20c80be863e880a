"""Model pre-split by octree (seed 002 §3.4): one big mesh becomes chunks of at most ``face_limit``
faces, so that a chunk rarely spans several tiles and per-tile culling can skip most of a mesh.

The seed subdivides a leaf's bounding box into eight while it holds too many faces, keeping only
non-empty children. Here the root cell is the cube on the mesh's bounding box (:func:`octree_root`),
so cells are cubes at every level: compact chunks whose screen footprints stay small from any
viewpoint (docs/explanation/culling.md). The whole adaptive octree is found from Morton codes with two sorts and
no per-face loop (issue 31: linear-time preprocessing, tens of millions of faces a second):

1. the vertices are sorted by the Morton code of their position (:func:`morton_codes`, at
   :data:`MAX_DEPTH` levels): the mesh's new vertex order, so the vertices of a chunk sit together
   in memory (culled tiles fetch few) and a range of chunks uses a narrow range of vertices;
2. each face belongs to the cell of its first vertex in that order (the one of lowest code), and the
   faces are sorted by that vertex's new number: this lists every cell's faces contiguously, in
   depth-first octree order;
3. level by level, a cell within the limit becomes a chunk, the others are split; the cells are
   found over the runs of faces that share a first vertex (at most the vertices), not face by face.

Each sort is one ``numpy.sort`` of 64-bit keys that hold the code (or the vertex's new number) above
the item's number, so no ``argsort`` is needed (numpy sorts such keys with SIMD). The passes between
the sorts run a block at a time on threads (:func:`node.scene.face_pass.for_blocks`).
Chunk ``i`` is ``split.faces[starts[i]:ends[i]]``: the renderer keeps one
index buffer and draws ranges. Chunks come in Morton order, so neighbouring chunks are neighbours in
space and visible chunks often form longer contiguous ranges.

Interpretation: a cell still over the limit at ``max_depth`` (all its faces' first vertices quantise
to one point) cannot be split in space; it is cut into consecutive pieces of ``face_limit`` faces,
so the limit always holds.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from node.scene import compiled
from node.scene.face_pass import face_pass, for_blocks

#: Default most faces per chunk: about the largest limit that keeps sort-first redundancy
#: (triangles drawn by 16 tiles / by the whole frame, both culled) within 1.10 (docs/explanation/culling.md).
DEFAULT_FACE_LIMIT = 192
#: Octree depth of the Morton codes: 12 bits per axis, 4096 cells along the root cube's side, so a
#: code (36 bits) and an item number up to 2**28 share one 64-bit sort key.
MAX_DEPTH = 12
#: Items (vertices, faces) numbered in a sort key's low bits.
ITEM_BITS = 64 - 3 * MAX_DEPTH


def _spread_table(bits: int) -> np.ndarray:
    """(2**bits,) uint64: each value's bits spread three apart (bit b to bit 3b)."""
    values = np.arange(1 << bits, dtype=np.uint64)
    spread = np.zeros_like(values)
    for bit in range(bits):
        spread |= ((values >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit)
    return spread


_SPREAD = _spread_table(MAX_DEPTH)
#: One face's three uint32 indices, one point's three float32 coordinates, as one record: numpy
#: takes records 3x faster than rows of (N, 3) arrays.
_FACE_RECORD = np.dtype([("a", "<u4"), ("b", "<u4"), ("c", "<u4")])
_POINT_RECORD = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])


@dataclass(frozen=True, slots=True)
class ChunkSplit:
    """A mesh's chunks and its new order.

    ``vertex_order`` (V,) int64: new vertex k is old vertex ``vertex_order[k]``; ``face_order`` (F,)
    int64: new face k is old face ``face_order[k]``; ``faces`` (F, 3) uint32: the faces in the new
    order, numbering the vertices in the new order. ``starts``/``ends`` (C,) int64: chunk i is new
    faces [starts[i], ends[i]). ``bounds`` (C, 2, 3) float32: each chunk's tight [min, max] box over
    its faces' vertices. ``depths`` (C,) int64: octree level of its cell. ``normals`` (V, 3) float32:
    the smooth vertex normals in the new order, when asked for; ``positions`` (V, 3) float32: the
    positions in the new order.
    """

    vertex_order: np.ndarray
    face_order: np.ndarray | None
    faces: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    bounds: np.ndarray
    depths: np.ndarray
    normals: np.ndarray | None = None
    positions: np.ndarray | None = None

    @property
    def chunk_count(self) -> int:
        return int(self.starts.size)

    @property
    def face_counts(self) -> np.ndarray:
        """(C,) int64 faces per chunk."""
        return self.ends - self.starts

    def reorder(self, faces: np.ndarray) -> np.ndarray:
        """The old (F, 3) index buffer with faces in chunk order, still numbering the old vertices
        (same dtype as ``faces``); needs :attr:`face_order`."""
        assert self.face_order is not None, "split without its face order"
        return np.ascontiguousarray(faces[self.face_order])


def octree_root(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) float64 of the root cell: the cube with the bounding box's low corner and its
    longest side, over ``positions`` (V, 3)."""
    points = np.asarray(positions)
    columns = [points[:, axis] for axis in range(3)]     # a column's reduction runs ~20x faster than axis=0's
    lo = np.array([column.min() for column in columns], np.float64)
    side = float((np.array([column.max() for column in columns], np.float64) - lo).max())
    return lo, lo + side


def morton_codes(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, depth: int = MAX_DEPTH) -> np.ndarray:
    """(N,) uint64 Morton codes of ``points`` (N, 3) in the box [lo, hi] at octree ``depth`` (≤
    :data:`MAX_DEPTH`).

    Bits 3·(depth−L)…3·(depth−L)+2 of a code name the child taken at level L, so a code shifted
    right by 3·(depth−L) names the level-L cell (each level halves the box along every axis).
    """
    if not 0 <= depth <= MAX_DEPTH:
        raise ValueError(f"depth must be in [0, {MAX_DEPTH}], got {depth}")
    points = np.asarray(points)
    lo = np.asarray(lo, np.float64)
    cells = 1 << depth
    scale = cells / np.maximum(np.asarray(hi, np.float64) - lo, np.finfo(np.float64).tiny)
    codes = np.zeros(len(points), np.uint64)

    def block(first: int, end: int) -> None:
        cell = np.empty(end - first, np.float64)
        index = np.empty(end - first, np.intp)
        for axis, shift in ((0, 2), (1, 1), (2, 0)):
            np.subtract(points[first:end, axis], lo[axis], out=cell)
            cell *= scale[axis]
            np.clip(cell, 0, cells - 1, out=cell)
            index[:] = cell
            codes[first:end] |= _SPREAD.take(index, mode="clip") << np.uint64(shift)

    for_blocks(len(points), block)
    return codes


def sorted_by_code(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(order (N,) int64, sorted codes (N,) uint64) of ``codes`` (N,) uint64 < 2**(64 − item bits):
    a stable sort by code, by one ``numpy.sort`` of keys holding the code above the item's number."""
    count = codes.size
    item_bits = max(1, int(count - 1).bit_length())
    code_bits = int(codes.max()).bit_length() if count else 0
    if code_bits > 64 - item_bits:
        order = np.argsort(codes, kind="stable")
        return order, codes[order]
    keys = np.empty(count, np.uint64)

    def pack(first: int, end: int) -> None:
        np.left_shift(codes[first:end], np.uint64(item_bits), out=keys[first:end])
        keys[first:end] |= np.arange(first, end, dtype=np.uint64)

    for_blocks(count, pack)
    if compiled.available(count):
        keys = compiled.radix_sort(keys, item_bits, max(code_bits, 1))
    else:
        keys.sort()
    order = np.empty(count, np.int64)

    def unpack(first: int, end: int) -> None:
        np.bitwise_and(keys[first:end], np.uint64((1 << item_bits) - 1), out=order[first:end], casting="unsafe")
        keys[first:end] >>= np.uint64(item_bits)

    for_blocks(count, unpack)
    return order, keys


def octree_split(positions: np.ndarray, faces: np.ndarray, face_limit: int = DEFAULT_FACE_LIMIT,
                 max_depth: int = MAX_DEPTH, normals: bool = False, face_order: bool = True) -> ChunkSplit:
    """Split a mesh (``positions`` (V, 3) float32, ``faces`` (F, 3) integer) into octree chunks of
    at most ``face_limit`` faces each; every face lands in exactly one chunk. ``normals``: also its
    smooth vertex normals, in the new vertex order (:mod:`node.scene.face_pass`); ``face_order``:
    keep :attr:`ChunkSplit.face_order` (an ingest, which needs only the new faces, skips it: 8 bytes
    a face written at random)."""
    if face_limit < 1:
        raise ValueError(f"face_limit must be ≥ 1, got {face_limit}")
    if not 0 <= max_depth <= MAX_DEPTH:
        raise ValueError(f"max_depth must be in [0, {MAX_DEPTH}], got {max_depth}")
    positions = np.asarray(positions, dtype=np.float32)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"expected positions (V, 3) and faces (F, 3), got {positions.shape} {faces.shape}")
    face_total, vertex_total = faces.shape[0], positions.shape[0]
    if face_total == 0:
        empty = np.zeros(0, np.int64)
        return ChunkSplit(np.arange(vertex_total), empty, np.zeros((0, 3), np.uint32), empty, empty,
                          np.zeros((0, 2, 3), np.float32), empty, None, positions)

    lo, hi = octree_root(positions)
    fused = compiled.sorted_vertices(positions, lo, hi, max_depth, _SPREAD) if compiled.available(face_total) else None
    if fused is not None:
        vertex_order, vertex_codes, rank = fused
    else:
        vertex_order, vertex_codes = sorted_by_code(morton_codes(positions, lo, hi, max_depth))
        rank = np.empty(vertex_total, np.uint32)
        rank[vertex_order] = np.arange(vertex_total, dtype=np.uint32)
    if compiled.available(face_total):   # the same arrays in compiled passes
        new_faces, kept_order, groups, group_codes = compiled.sorted_faces(faces, rank, vertex_codes, face_order)
        del rank, vertex_codes
        starts, ends, depths = compiled.octree_cells(group_codes, groups, face_total, face_limit, max_depth)
        del groups, group_codes
        moved = _moved(positions, vertex_order)    # made once the sort's arrays are gone: a lower peak
        swept = face_pass(moved, new_faces, starts, normals)
        return ChunkSplit(vertex_order, kept_order, new_faces, starts, ends, swept.boxes, depths, swept.normals, moved)
    # Faces sorted by their first vertex in the new order, then by number: one sort of keys that hold both.
    item_bits = max(1, int(face_total - 1).bit_length())
    renumbered = np.empty((face_total, 3), np.uint32)
    keys = np.empty(face_total, np.uint64)

    def renumber(first: int, end: int, renumbered: np.ndarray = renumbered, rank: np.ndarray = rank,
                 keys: np.ndarray = keys) -> None:
        block = renumbered[first:end]
        block[:] = rank.take(faces[first:end].astype(np.intp, copy=False))
        lowest = np.minimum(np.minimum(block[:, 0], block[:, 1]), block[:, 2]).astype(np.uint64)
        np.bitwise_or(lowest << np.uint64(item_bits), np.arange(first, end, dtype=np.uint64), out=keys[first:end])

    for_blocks(face_total, renumber)
    del renumber, rank
    keys.sort()
    order = np.empty(face_total, np.int64)
    new_faces = np.empty((face_total, 3), np.uint32)
    group_start = np.empty(face_total, bool)

    def reorder(first: int, end: int, rows: np.ndarray = renumbered.view(_FACE_RECORD).reshape(-1),
                new_rows: np.ndarray = new_faces.view(_FACE_RECORD).reshape(-1), keys: np.ndarray = keys,
                group_start: np.ndarray = group_start) -> None:
        rows_order = order[first:end]
        np.bitwise_and(keys[first:end], np.uint64((1 << item_bits) - 1), out=rows_order, casting="unsafe")
        rows.take(rows_order, out=new_rows[first:end], mode="clip")
        lowest = keys[max(first - 1, 0):end] >> np.uint64(item_bits)
        group_start[first] = first == 0 or lowest[0] != lowest[1]
        np.not_equal(lowest[1 + (first > 0):], lowest[(first > 0):-1], out=group_start[first + 1:end])

    for_blocks(face_total, reorder)
    del reorder, renumbered
    groups = np.flatnonzero(group_start)
    group_codes = vertex_codes.take((keys.take(groups) >> np.uint64(item_bits)).astype(np.intp))
    del keys, group_start
    starts, ends, depths = _cells(group_codes, groups, face_total, face_limit, max_depth)
    moved = _moved(positions, vertex_order)
    swept = face_pass(moved, new_faces, starts, normals)
    return ChunkSplit(vertex_order, order if face_order else None, new_faces, starts, ends, swept.boxes, depths,
                      swept.normals, moved)


def _moved(positions: np.ndarray, vertex_order: np.ndarray) -> np.ndarray:
    """``positions`` (V, 3) float32 in the new vertex order (``vertex_order`` (V,) int64), taken as
    records a block at a time on threads."""
    moved = np.empty_like(positions)
    points = np.ascontiguousarray(positions).view(_POINT_RECORD).reshape(-1)
    moved_points = moved.view(_POINT_RECORD).reshape(-1)

    def move(first: int, end: int) -> None:
        points.take(vertex_order[first:end], out=moved_points[first:end], mode="clip")

    for_blocks(len(positions), move)
    return moved


def moved_split(split: ChunkSplit, positions: np.ndarray, normals: bool = False) -> ChunkSplit:
    """``split``'s chunks, of the same faces, over their vertices moved to ``positions`` (V, 3) (in the
    old vertex order): a simulation's next step (issue 33), split with no sort. The vertex and face
    orders stay; the chunks' boxes and, with ``normals``, the smooth normals are those of the new
    positions. Valid for any positions (the boxes are tight); compact while the vertices moved
    little relative to the chunks' size."""
    moved = np.asarray(positions, np.float32).take(split.vertex_order, axis=0)
    swept = face_pass(moved, split.faces, split.starts, normals)
    return dataclasses.replace(split, bounds=swept.boxes, normals=swept.normals, positions=moved)


def _cells(codes: np.ndarray, group_faces: np.ndarray, face_total: int, face_limit: int,
           max_depth: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(starts, ends, depths) (C,) int64 of the adaptive octree's leaves over ``face_total`` faces
    in groups of one code: group g holds the faces from ``group_faces[g]`` (G,) int64 (0 first) to
    the next group's, its code ``codes[g]`` (G,) uint64, sorted.

    Two neighbours in code order first fall into different cells at the level of their codes'
    highest differing bit, so each cell boundary is found once, with its level; then level by level
    the cells still over the limit are cut at that level's boundaries. Work grows with the groups
    (at most the vertices), not with the faces times the depth."""
    differing = codes[1:] ^ codes[:-1]
    highest = np.frexp(differing.astype(np.float64))[1] - 1          # highest set bit; -1 where equal
    boundary_level = np.where(differing > 0, max_depth - highest // 3, max_depth + 1).astype(np.int8)
    del differing, highest
    # Each level's boundaries (the first group of a cell), in order: one stable radix sort by level.
    by_level = np.argsort(boundary_level, kind="stable")
    level_bounds = np.searchsorted(boundary_level[by_level], np.arange(max_depth + 2))
    del boundary_level
    found_starts, found_ends, found_depths = [], [], []
    open_starts, open_ends = np.zeros(1, np.int64), np.full(1, face_total, np.int64)
    for depth in range(max_depth + 1):
        if depth > 0:
            cuts = group_faces.take(by_level[level_bounds[depth]:level_bounds[depth + 1]].astype(np.int64) + 1)
            inside = np.searchsorted(open_starts, cuts, side="right") - 1
            cuts = cuts[(inside >= 0) & (cuts < open_ends[np.maximum(inside, 0)])]
            bounds = np.sort(np.concatenate([open_starts, cuts]))   # disjoint: a cut is no cell's start yet
            ends = np.append(bounds[1:], 0)
            last = np.searchsorted(bounds, open_ends, side="left") - 1     # the last piece of each open cell
            ends[last] = open_ends
            open_starts, open_ends = bounds, ends
        small = open_ends - open_starts <= face_limit
        found_starts.append(open_starts[small])
        found_ends.append(open_ends[small])
        found_depths.append(np.full(int(small.sum()), depth, np.int64))
        open_starts, open_ends = open_starts[~small], open_ends[~small]
        if open_starts.size == 0:
            break
    if open_starts.size:  # cells that cannot be split in space: cut them into limit-sized pieces
        lengths = open_ends - open_starts
        pieces = -(-lengths // face_limit)
        first = np.repeat(open_starts, pieces) + face_limit * (
            np.arange(int(pieces.sum())) - np.repeat(np.cumsum(pieces) - pieces, pieces))
        found_starts.append(first)
        found_ends.append(np.minimum(first + face_limit, np.repeat(open_ends, pieces)))
        found_depths.append(np.full(first.size, max_depth, np.int64))
    starts = np.concatenate(found_starts)
    order = np.argsort(starts)
    return starts[order], np.concatenate(found_ends)[order], np.concatenate(found_depths)[order]


def chunk_boxes(positions: np.ndarray, faces: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """(C, 2, 3) float32 tight [min, max] boxes of the chunks that start at faces ``starts`` (C,) of
    ``faces`` (F, 3) over ``positions`` (V, 3) float32 (each chunk runs to the next one's start)."""
    return face_pass(positions, faces, starts, normals=False).boxes
