"""Scene chunks (seed 002 §3.4): at load time every batch over the face limit is pre-split by
octree (:func:`node.scene.octree.octree_split`). The chunk boxes are what per-tile culling tests
(seed 001); the tree over them is built by the culling package (:mod:`node.culling.bvh`). No GL
here.

Splitting only re-orders a batch's faces, and its vertices into Morton order (so a chunk's vertices
sit together in memory, which makes culled tiles faster on llvmpipe: docs/explanation/culling.md); attribute
values and materials stay. A batch without normals gets its smooth normals once its vertices have
their final order (:mod:`node.scene.normals`). The renderer's one index buffer
(batches in order, 3 indices per face) holds every chunk as a contiguous index range. Chunks are
numbered in that buffer's order, so chunk i + 1 starts where chunk i ends.

The split must never change the image. Under the depth test, opaque and alpha-masked triangles give
the same pixels in any order, except exactly coplanar overlaps (z-fighting), where the first drawn
wins; blending depends on draw order everywhere. So blended batches keep their face order and stay
one chunk each (they are still culled as a whole).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from node.culling.bvh import ChunkBVH
from node.scene.mesh import MeshBatch
from node.scene.normals import smooth_vertex_normals
from node.scene.octree import DEFAULT_FACE_LIMIT, ChunkSplit, octree_split

#: Most primitive groups sent to the coordinator (seed 003's DPBP). The coordinator projects them
#: and its ``*-predict`` balancers sweep a box per group (and per group–tile overlap) every frame, so
#: its CPU per frame grows with them; the balance does not (``bench.balance``, adaptive-predict, 3
#: nodes, 1280x720, orbits: imbalance mean at 4000 / 1024 / 512 groups: builtin:cluster 1.036 /
#: 1.041 / 1.036, pan 1.032 / 1.029 / 1.031, lucy 1.083 / 1.028 / 1.036), while a partition's CPU
#: fell from 3.7 ms (cluster, 2181 groups) and 4.8 ms (pan, 3021) to 1.5 and 1.6 ms at 512.
MAX_GROUPS = 512


@dataclass(frozen=True, eq=False)
class PrimitiveGroups:
    """World-space primitive groups for seed 003's DPBP estimate (chunks, or runs of chunks of one
    object), at the base pose.

    ``boxes`` (K, 6) float64 as x0, y0, z0, x1, y1, z1; ``counts`` (K,) int64 triangles;
    ``owners`` (K,) int64 the object each group belongs to (issue 11: groups move with it);
    ``chunk_starts`` (K,) int64: group i is the chunks from ``chunk_starts[i]`` to the next group's.
    """

    boxes: np.ndarray
    counts: np.ndarray
    owners: np.ndarray
    chunk_starts: np.ndarray


@dataclass(frozen=True, slots=True)
class DrawRuns:
    """Index ranges to draw, in draw order, none across a batch boundary.

    ``batch`` (R,) int64 batch of each run; ``first`` (R,) int64 first index in the scene's index
    buffer; ``count`` (R,) int64 indices (3 per triangle); ``chunks``: how many chunks they cover.
    """

    batch: np.ndarray
    first: np.ndarray
    count: np.ndarray
    chunks: int

    @property
    def triangles(self) -> int:
        return int(self.count.sum()) // 3

    def batch_slices(self) -> list[tuple[int, int, int]]:
        """(batch, first run, run count) for each batch that has runs, in draw order."""
        if self.batch.size == 0:
            return []
        starts = np.flatnonzero(np.concatenate(([True], self.batch[1:] != self.batch[:-1])))
        counts = np.diff(np.append(starts, self.batch.size))
        return [(int(b), int(s), int(c)) for b, s, c in zip(self.batch[starts], starts, counts, strict=True)]


@dataclass(frozen=True, eq=False)
class SceneChunks:
    """The chunks of a scene.

    ``batch`` (C,) int64: the batch each chunk belongs to; ``index_bounds`` (C + 1,) int64: chunk i
    is indices [index_bounds[i], index_bounds[i + 1]) of the scene's index buffer; ``batch_bounds``
    (B + 1,) int64: batch b is chunks [batch_bounds[b], batch_bounds[b + 1]); ``boxes`` (C, 2, 3)
    float32 world-space [min, max] of each chunk's faces; ``face_limit`` the limit the batches were
    split with; ``tree`` the culling tree over ``boxes`` when it was read with them (a scene cache
    entry keeps it), else None (the culler builds it: :func:`node.culling.bvh.build_chunk_bvh`).
    """

    batch: np.ndarray
    index_bounds: np.ndarray
    batch_bounds: np.ndarray
    boxes: np.ndarray
    face_limit: int
    tree: ChunkBVH | None = None

    @property
    def chunk_count(self) -> int:
        return int(self.batch.size)

    @property
    def face_counts(self) -> np.ndarray:
        """(C,) int64 triangles per chunk."""
        return np.diff(self.index_bounds) // 3

    def runs(self, first_chunks: np.ndarray, end_chunks: np.ndarray) -> DrawRuns:
        """Draw runs for the disjoint chunk ranges [first_chunks[i], end_chunks[i]) (R,), sorted:
        each range becomes one index range per batch it touches."""
        first = np.asarray(first_chunks, dtype=np.int64)
        end = np.asarray(end_chunks, dtype=np.int64)
        if first.size == 0:
            empty = np.zeros(0, np.int64)
            return DrawRuns(empty, empty, empty, 0)
        first_batch, last_batch = self.batch[first], self.batch[end - 1]
        pieces = last_batch - first_batch + 1
        owner = np.repeat(np.arange(first.size), pieces)
        batch = first_batch[owner] + np.arange(owner.size) - np.repeat(np.cumsum(pieces) - pieces, pieces)
        piece_first = np.maximum(first[owner], self.batch_bounds[batch])
        piece_end = np.minimum(end[owner], self.batch_bounds[batch + 1])
        index_first = self.index_bounds[piece_first]
        return DrawRuns(batch, index_first, self.index_bounds[piece_end] - index_first, int((end - first).sum()))

    def all_runs(self) -> DrawRuns:
        """One run per batch: the whole scene, as drawn without culling."""
        return self.runs(np.zeros(1, np.int64), np.array([self.chunk_count]))

    def primitive_groups(self, batch_owner: np.ndarray | None = None, max_groups: int = MAX_GROUPS) -> PrimitiveGroups:
        """Chunk boxes and triangle counts; above ``max_groups`` chunks, consecutive chunks (octree
        neighbours) are merged into equal runs, never across two objects (``batch_owner`` (B,) int64:
        each batch's object; None: all one object), so that at most ``max_groups`` groups remain
        plus one per change of object in chunk order."""
        owner = np.zeros(self.chunk_count, np.int64) if batch_owner is None else np.asarray(batch_owner)[self.batch]
        per_group = -(-self.chunk_count // max_groups)
        changes = np.flatnonzero(np.diff(owner)) + 1
        starts = np.union1d(np.arange(0, self.chunk_count, per_group), changes)
        lo = np.minimum.reduceat(self.boxes[:, 0], starts, axis=0)
        hi = np.maximum.reduceat(self.boxes[:, 1], starts, axis=0)
        counts = np.add.reduceat(self.face_counts, starts)
        return PrimitiveGroups(np.concatenate([lo, hi], axis=1).astype(np.float64), counts.astype(np.int64),
                               owner[starts].astype(np.int64), starts.astype(np.int64))


#: How a batch over the face limit is split: (batch, face limit) → its chunks, with its smooth
#: normals when it has none.
Splitter = Callable[[MeshBatch, int], ChunkSplit]


def octree_chunks(batch: MeshBatch, face_limit: int) -> ChunkSplit:
    """The default :data:`Splitter`: ``batch`` split by octree (:func:`node.scene.octree.octree_split`)."""
    return octree_split(batch.positions, batch.faces, face_limit, normals=batch.normals is None, face_order=False)


def split_batches(batches: Sequence[MeshBatch], face_limit: int = DEFAULT_FACE_LIMIT,
                  splitter: Splitter = octree_chunks) -> tuple[list[MeshBatch], SceneChunks]:
    """Split every non-blended batch over ``face_limit`` faces with ``splitter``; returns the batches
    (faces and vertices re-ordered where split, smooth normals computed where missing) and their
    :class:`SceneChunks`."""
    if face_limit < 1:
        raise ValueError(f"face limit must be ≥ 1, got {face_limit}")
    out, chunk_batch, face_counts, boxes = [], [], [], []
    for number, batch in enumerate(batches):
        if batch.alpha_mode == "BLEND" or batch.triangle_count <= face_limit:
            counts, batch_boxes = np.array([batch.triangle_count]), batch.bounds()[None].astype(np.float32)
        else:
            split = splitter(batch, face_limit)
            batch = batch.with_vertices(split.vertex_order, split.faces, split.positions)
            if split.normals is not None:
                batch = dataclasses.replace(batch, normals=split.normals)
            counts, batch_boxes = split.face_counts, split.bounds
        if batch.normals is None:
            batch = dataclasses.replace(batch, normals=smooth_vertex_normals(batch.positions, batch.faces))
        out.append(batch)
        chunk_batch.append(np.full(counts.size, number, np.int64))
        face_counts.append(counts)
        boxes.append(batch_boxes)
    chunk_faces = np.concatenate(face_counts).astype(np.int64)
    chunk_boxes = np.concatenate(boxes).astype(np.float32)
    batch_sizes = np.array([len(c) for c in face_counts], np.int64)
    chunks = SceneChunks(
        batch=np.concatenate(chunk_batch),
        index_bounds=np.concatenate(([0], np.cumsum(chunk_faces * 3))),
        batch_bounds=np.concatenate(([0], np.cumsum(batch_sizes))),
        boxes=chunk_boxes,
        face_limit=face_limit,
    )
    return out, chunks
