"""One pass over a mesh's faces, a block at a time on every core (issue 31): each chunk's box and,
when wanted, the smooth vertex normals. No GL here.

Each face's corners are fetched once (per axis, from contiguous columns), its normal is the cross
product of two edges (its length twice the face's area),
and its box is the corners' min and max. Chunk boxes are the faces' boxes reduced per chunk; vertex
normals are the face normals summed at their vertices by a sparse product per block over a window
of vertices: from the block's first face's first vertex to :data:`WINDOW_MARGIN` past its last
face's (after the octree split, where nearly all its corners lie). The few corners beyond it (faces
reaching across a cell boundary far in the vertex order) are summed apart, once, at the end.

The sums are taken in float64 over float32 face normals, which holds them exactly (a vertex's few
faces never span 2**29 in magnitude), so a vertex's normal does not depend on the order of its
faces: a mesh split into chunks of any size gets the very same normals, and the same picture.
numpy's gathers, arithmetic and scipy's product release the GIL, so the blocks run in threads.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from node.scene import compiled

#: Faces a block holds at least (blocks end at a chunk's end).
BLOCK_FACES = 1 << 18
#: Vertices past a block's last face's first vertex whose sums the block adds up in its window.
WINDOW_MARGIN = 1 << 16
#: Threads that run blocks (numpy releases the GIL in them).
WORKERS = max(1, min(4, os.cpu_count() or 1))


@dataclass(frozen=True, slots=True)
class FacePass:
    """What one pass gives: ``boxes`` (C, 2, 3) float32 tight [min, max] of each chunk's faces'
    corners; ``normals`` (V, 3) float32 unit smooth vertex normals (zero where no face with an area
    touches), or None when not asked for."""

    boxes: np.ndarray
    normals: np.ndarray | None


def for_blocks(total: int, work: Callable[[int, int], None], block: int = BLOCK_FACES) -> None:
    """``work(first, end)`` for consecutive blocks [first, end) of ``total`` items, on
    :data:`WORKERS` threads (numpy releases the GIL in the work's array operations)."""
    ranges = [(first, min(first + block, total)) for first in range(0, total, block)]
    if len(ranges) <= 1:
        for first, end in ranges:
            work(first, end)
        return
    with ThreadPoolExecutor(WORKERS) as pool:
        for _ in pool.map(lambda bounds: work(*bounds), ranges):
            pass


def _blocks(starts: np.ndarray, face_total: int) -> Iterator[tuple[int, int, int, int]]:
    """(first face, end face, first chunk, end chunk) of blocks of whole chunks of about
    :data:`BLOCK_FACES` faces, chunk i starting at face ``starts[i]``."""
    if face_total == 0:
        return
    bounds = np.append(starts, face_total)
    chunk = 0
    while chunk < starts.size:
        end_chunk = int(np.searchsorted(bounds, bounds[chunk] + BLOCK_FACES, side="left"))
        end_chunk = min(max(end_chunk, chunk + 1), starts.size)
        yield int(bounds[chunk]), int(bounds[end_chunk]), chunk, end_chunk
        chunk = end_chunk


def face_pass(positions: np.ndarray, faces: np.ndarray, starts: np.ndarray, normals: bool = True) -> FacePass:
    """Chunk boxes (chunk i is faces [starts[i], starts[i + 1]) of ``faces`` (F, 3) over
    ``positions`` (V, 3) float32) and, with ``normals``, the smooth vertex normals."""
    if compiled.available(len(faces)):
        return FacePass(*compiled.face_pass(positions, faces, starts, normals))
    # Imported here: a node that opens scene cache entries never needs it (0.2 s of its start-up).
    import scipy.sparse

    columns = [np.ascontiguousarray(positions[:, axis], np.float32) for axis in range(3)]
    starts = np.asarray(starts, np.int64)
    boxes = np.empty((starts.size, 2, 3), np.float32)
    summed = np.empty((len(positions), 3), np.float64) if normals else None
    blocks = list(_blocks(starts, len(faces)))
    most = max((end - first for first, end, _, _ in blocks), default=0)
    ones = np.ones(3 * most)
    wide = 3 * most >= 1 << 31 or len(positions) >= 1 << 31
    steps = np.arange(0, 3 * most + 1, 3, dtype=np.int64 if wide else np.int32)
    empty = np.zeros(0)

    def block(first: int, end: int, first_chunk: int, end_chunk: int) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        corners = faces[first:end]
        count = len(corners)
        index = [corners[:, k].astype(np.intp) for k in range(3)]
        a, b, c = ([column.take(i, mode="clip") for column in columns] for i in index)
        local = starts[first_chunk:end_chunk] - first
        for axis in range(3):
            low, high = np.minimum(a[axis], b[axis]), np.maximum(a[axis], b[axis])
            boxes[first_chunk:end_chunk, 0, axis] = np.minimum.reduceat(np.minimum(low, c[axis], out=low), local)
            boxes[first_chunk:end_chunk, 1, axis] = np.maximum.reduceat(np.maximum(high, c[axis], out=high), local)
        if summed is None:
            return 0, empty, empty, empty
        u = [np.subtract(b[axis], a[axis], out=b[axis]) for axis in range(3)]
        v = [np.subtract(c[axis], a[axis], out=c[axis]) for axis in range(3)]
        face_normal = np.empty((count, 3), np.float64)
        face_normal[:, 0] = u[1] * v[2] - u[2] * v[1]
        face_normal[:, 1] = u[2] * v[0] - u[0] * v[2]
        face_normal[:, 2] = u[0] * v[1] - u[1] * v[0]
        # Corners beyond the block's window (faces spanning far in the vertex order) are summed apart.
        lo = int(corners.min())
        flat = corners.reshape(-1) - corners.dtype.type(lo)
        rows = min(int(corners[-1].min()) - lo + WINDOW_MARGIN, int(flat.max()) + 1)
        far = np.flatnonzero(flat >= rows)
        rows_index = flat.astype(steps.dtype)
        rows_index[far] = rows
        incidence = scipy.sparse.csc_matrix((ones[:3 * count], rows_index, steps[:count + 1]), shape=(rows + 1, count))
        far_faces = face_normal.take(far // 3, axis=0)
        return lo, (incidence @ face_normal)[:rows], flat.take(far).astype(np.int64) + lo, far_faces

    far_index, far_normals = [], []
    filled = 0   # summed[:filled] written: windows start in order, a later one overlaps the earlier ones' ends only
    with ThreadPoolExecutor(WORKERS) as pool:
        for lo, window, index, normal in pool.map(lambda args: block(*args), blocks):
            if summed is not None:
                summed[filled:lo] = 0.0
                overlap = min(max(filled - lo, 0), len(window))
                summed[lo:lo + overlap] += window[:overlap]
                summed[lo + overlap:lo + len(window)] = window[overlap:]
                filled = max(filled, lo + len(window))
                far_index.append(index)
                far_normals.append(normal)
    if summed is None:
        return FacePass(boxes, None)
    summed[filled:] = 0.0
    np.add.at(summed, np.concatenate(far_index), np.concatenate(far_normals))
    unit = np.empty(summed.shape, np.float32)
    for_blocks(len(summed), lambda first, end: unit_vectors(summed[first:end], unit[first:end]))
    return FacePass(boxes, unit)


def unit_vectors(vectors: np.ndarray, out: np.ndarray) -> None:
    """``vectors`` (N, 3) scaled to unit length into ``out`` (N, 3) (any float dtype); zero vectors stay zero."""
    lengths = np.sqrt(np.einsum("ij,ij->i", vectors, vectors))
    inverse = np.divide(1.0, lengths, out=np.zeros_like(lengths), where=lengths > 0.0)
    np.multiply(vectors, inverse[:, None], out=out, casting="unsafe")


def normalized(vectors: np.ndarray) -> np.ndarray:
    """``vectors`` (N, 3) scaled to unit length; zero vectors stay zero (same dtype)."""
    lengths = np.sqrt(np.einsum("ij,ij->i", vectors, vectors))
    return np.divide(vectors, lengths[:, None], out=np.zeros_like(vectors), where=lengths[:, None] > 0.0)
