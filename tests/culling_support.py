"""Test-only culling references and read-backs: a tile's planes straight from its camera, the flat
per-chunk box test the tree traversal must match, merged index ranges, what a GPU culler kept, and
the tile-sized viewport the renderer does not use (it scissors a frame-sized framebuffer)."""

from __future__ import annotations

import numpy as np

from node.culling.bvh import ChunkBVH, range_members
from node.culling.frustum import DEFAULT_PAD_PX, frustum_planes_from_matrix
from node.culling.gpu import GpuCuller
from tessera.geometry import Camera, Rect, view_projection


def tile_frustum_planes(camera: Camera, size: tuple[int, int], rect: Rect, bounds: np.ndarray,
                        pad_px: float = DEFAULT_PAD_PX) -> np.ndarray:
    """(6, 4) float64 world-space planes of ``rect``'s sub-frustum, from the same
    :func:`view_projection` (near/far from the scene ``bounds`` (2, 3)) that the renderer draws with."""
    return frustum_planes_from_matrix(view_projection(camera, size, bounds), size, rect, pad_px)


def classify_boxes(lo: np.ndarray, hi: np.ndarray, planes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For boxes ``lo``/``hi`` (K, 3) and ``planes`` (P, 4): (outside, inside) (K, P) bool — the box
    lies wholly on the negative side (p-vertex test), or wholly on the positive side (n-vertex)."""
    center = (lo + hi) * 0.5
    extent = (hi - lo) * 0.5
    distance = center @ planes[:, :3].T + planes[:, 3]
    radius = extent @ np.abs(planes[:, :3]).T
    return distance + radius < 0.0, distance - radius >= 0.0


def cull_flat(bvh: ChunkBVH, planes: np.ndarray) -> np.ndarray:
    """(K,) int64 sorted chunks kept by testing every leaf box against ``planes`` (6, 4) at once —
    the same set as :func:`node.culling.bvh.cull`, without the hierarchy."""
    leaves = np.flatnonzero(bvh.left < 0)
    outside, _ = classify_boxes(bvh.lo[leaves], bvh.hi[leaves], np.asarray(planes, dtype=np.float64))
    return np.sort(bvh.first_chunk[leaves[~outside.any(axis=1)]]).astype(np.int64)


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


def read_commands(culler: GpuCuller) -> np.ndarray:
    """(C, 5) uint32 commands of ``culler``'s last cull (a GPU→CPU read: waits for the GPU)."""
    return np.frombuffer(culler.commands.read(), np.uint32).reshape(-1, 5)


def read_visible_chunks(culler: GpuCuller) -> np.ndarray:
    """(K,) int64 sorted ids of the chunks ``culler``'s last cull kept (reads the commands back)."""
    commands = read_commands(culler)
    drawn = commands[commands[:, 0] > 0]
    index_starts = culler.gpu_bvh.index_starts
    first = np.searchsorted(index_starts, drawn[:, 2])
    end = np.searchsorted(index_starts, drawn[:, 2].astype(np.int64) + drawn[:, 0])
    return np.sort(range_members(first, end))


def read_input_nodes(culler: GpuCuller) -> np.ndarray:
    """(T,) uint32 sorted: the input cut ``culler``'s next cull starts from."""
    data = np.frombuffer(culler.inputs[0].read(), np.uint32)
    return np.sort(data[4:4 + data[3]])


def tile_viewport(rect: Rect, size: tuple[int, int]) -> tuple[int, int, int, int]:
    """GL viewport (x, y, w, h) that draws the full ``size`` frame shifted so ``rect`` lands on a
    ``rect.w``×``rect.h`` framebuffer."""
    width, height = size
    return (-rect.x, rect.y + rect.h - height, width, height)
