"""Model pre-split by octree (seed 002 §3.4): one big mesh becomes chunks of at most ``face_limit``
faces, so that a chunk rarely spans several tiles and per-tile culling can skip most of a mesh.

The seed subdivides a leaf's bounding box into eight while it holds too many faces, keeping only
non-empty children. Here the root cell is the cube on the mesh's bounding box (:func:`octree_root`),
so cells are cubes at every level: compact chunks whose screen footprints stay small from any
viewpoint (the same tile redundancy with fewer chunks than halving an elongated box:
docs/explanation/culling.md). Every face goes to the octree cell holding its centroid; the whole adaptive
octree is found at once from the faces' Morton codes (sorting by code lists every cell's faces
contiguously, in depth-first octree order), level by level with numpy, no per-face loop.

Only the face order changes: vertices, normals and materials stay as they are. Chunk ``i`` is
``faces[face_order][starts[i]:ends[i]]``, so the renderer keeps one index buffer and draws ranges.
Chunks come in octree depth-first (Morton) order, so neighbouring chunks are neighbours in space and
visible chunks often form longer contiguous ranges.

Interpretation: a cell still over the limit at ``max_depth`` (all its centroids quantise to one
point, e.g. many faces sharing a centroid) cannot be split in space; it is cut into consecutive
pieces of ``face_limit`` faces, so the limit always holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Default most faces per chunk: about the largest limit that keeps sort-first redundancy
#: (triangles drawn by 16 tiles / by the whole frame, both culled) within 1.10 (docs/explanation/culling.md).
DEFAULT_FACE_LIMIT = 192
#: Octree depth of the Morton code (21 bits per axis fill a uint64).
MAX_DEPTH = 21


@dataclass(frozen=True, slots=True)
class ChunkSplit:
    """Chunks of one mesh as contiguous ranges of its re-ordered faces.

    ``face_order`` (F,) int64: new face k is old face ``face_order[k]``. ``starts``/``ends`` (C,)
    int64: chunk i is new faces [starts[i], ends[i]). ``bounds`` (C, 2, 3) float32: each chunk's
    tight [min, max] box over its faces' vertices. ``depths`` (C,) int64: octree level of its cell.
    """

    face_order: np.ndarray
    starts: np.ndarray
    ends: np.ndarray
    bounds: np.ndarray
    depths: np.ndarray

    @property
    def chunk_count(self) -> int:
        return int(self.starts.size)

    @property
    def face_counts(self) -> np.ndarray:
        """(C,) int64 faces per chunk."""
        return self.ends - self.starts

    @property
    def index_starts(self) -> np.ndarray:
        """(C,) int64 first index of each chunk in the re-ordered triangle index buffer."""
        return self.starts * 3

    @property
    def index_ends(self) -> np.ndarray:
        """(C,) int64 one past each chunk's last index in the re-ordered index buffer."""
        return self.ends * 3

    def reorder(self, faces: np.ndarray) -> np.ndarray:
        """The (F, 3) index buffer with faces in chunk order (same dtype as ``faces``)."""
        return np.ascontiguousarray(faces[self.face_order])


def _spread_bits(values: np.ndarray) -> np.ndarray:
    """Insert two zero bits after each of the low 21 bits of ``values`` (uint64)."""
    v = values.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def octree_root(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) (3,) float64 of the root cell: the cube with the bounding box's low corner and its
    longest side, over ``positions`` (V, 3)."""
    lo = np.asarray(positions, dtype=np.float64).min(axis=0)
    side = float((np.asarray(positions, dtype=np.float64).max(axis=0) - lo).max())
    return lo, lo + side


def morton_codes(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, depth: int = MAX_DEPTH) -> np.ndarray:
    """(N,) uint64 Morton codes of ``points`` (N, 3) in the box [lo, hi] at octree ``depth``.

    Bits 3·(depth−L)…3·(depth−L)+2 of a code name the child taken at level L, so a code shifted
    right by 3·(depth−L) names the level-L cell (each level halves the box along every axis).
    """
    extent = np.maximum(np.asarray(hi, np.float64) - lo, np.finfo(np.float64).tiny)
    cells = float(1 << depth)
    grid = np.floor((np.asarray(points, np.float64) - lo) / extent * cells)
    grid = np.clip(grid, 0, cells - 1).astype(np.uint64)
    return (_spread_bits(grid[:, 0]) << np.uint64(2)) | (_spread_bits(grid[:, 1]) << np.uint64(1)) | \
        _spread_bits(grid[:, 2])


def octree_split(positions: np.ndarray, faces: np.ndarray, face_limit: int = DEFAULT_FACE_LIMIT,
                 max_depth: int = MAX_DEPTH) -> ChunkSplit:
    """Split a mesh (``positions`` (V, 3) float32, ``faces`` (F, 3) integer) into octree chunks of
    at most ``face_limit`` faces each; every face lands in exactly one chunk."""
    if face_limit < 1:
        raise ValueError(f"face_limit must be ≥ 1, got {face_limit}")
    if not 0 <= max_depth <= MAX_DEPTH:
        raise ValueError(f"max_depth must be in [0, {MAX_DEPTH}], got {max_depth}")
    positions = np.asarray(positions, dtype=np.float32)
    faces = np.asarray(faces)
    if positions.ndim != 2 or positions.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError(f"expected positions (V, 3) and faces (F, 3), got {positions.shape} {faces.shape}")
    face_total = faces.shape[0]
    if face_total == 0:
        empty = np.zeros(0, np.int64)
        return ChunkSplit(empty, empty, empty, np.zeros((0, 2, 3), np.float32), empty)

    corner_a, corner_b, corner_c = (positions[faces[:, k]] for k in range(3))
    centroids = (corner_a + corner_b + corner_c) / np.float32(3.0)
    codes = morton_codes(centroids, *octree_root(positions), max_depth)
    face_order = np.argsort(codes, kind="stable")
    codes = codes[face_order]

    found_starts, found_counts, found_depths = [], [], []
    active = np.arange(face_total)  # sorted positions of faces whose cell is still over the limit
    for depth in range(max_depth + 1):
        prefix = codes[active] >> np.uint64(3 * (max_depth - depth))
        cell_first = np.flatnonzero(np.concatenate(([True], prefix[1:] != prefix[:-1])))
        counts = np.diff(np.append(cell_first, active.size))
        small = counts <= face_limit
        found_starts.append(active[cell_first[small]])
        found_counts.append(counts[small])
        found_depths.append(np.full(int(small.sum()), depth))
        active = active[np.repeat(~small, counts)]
        if active.size == 0:
            break
    if active.size:  # cells that cannot be split in space: cut them into limit-sized pieces
        leftover = codes[active]
        cell_first = np.flatnonzero(np.concatenate(([True], leftover[1:] != leftover[:-1])))
        rank = np.arange(active.size) - np.repeat(cell_first, np.diff(np.append(cell_first, active.size)))
        piece_first = np.flatnonzero(rank % face_limit == 0)
        found_starts.append(active[piece_first])
        found_counts.append(np.diff(np.append(piece_first, active.size)))
        found_depths.append(np.full(piece_first.size, max_depth))

    starts = np.concatenate(found_starts).astype(np.int64)
    order = np.argsort(starts)
    starts = starts[order]
    ends = starts + np.concatenate(found_counts).astype(np.int64)[order]
    depths = np.concatenate(found_depths).astype(np.int64)[order]
    face_lo = np.minimum(np.minimum(corner_a, corner_b), corner_c)[face_order]
    face_hi = np.maximum(np.maximum(corner_a, corner_b), corner_c)[face_order]
    bounds = np.stack([np.minimum.reduceat(face_lo, starts, axis=0),
                       np.maximum.reduceat(face_hi, starts, axis=0)], axis=1)
    return ChunkSplit(face_order.astype(np.int64), starts, ends, bounds, depths)
