"""Levels of detail (issue 32): a cluster DAG of coarser versions of a scene's big batches (as
Nanite's), built once per scene cache entry and stored beside it. No GL here; the per-frame choice is
:mod:`node.culling.lod`.

A batch's chunks, in their Morton order, are cut into **leaves** of about :data:`CLUSTER_FACES`
faces (runs of whole chunks): the full-detail clusters. Each level then **groups** the clusters of
the level below that share the most border (a greedy merge of neighbours up to about
:data:`GROUP_FACES` faces), simplifies each group's faces to about :data:`KEEP` of them with the
group's border locked (meshoptimizer's ``simplify``), and **splits** the result into clusters of
about :data:`CLUSTER_FACES` faces (runs of its triangles in Morton order). The next level regroups
those with other neighbours, so a border locked at one level lies inside a group at the next and is
simplified there: each coarse level keeps about :data:`KEEP` of the one below, down to a few clusters
a batch (a level stops where no group could be simplified to at most :data:`MAX_KEPT` of its faces).

A **group** is replaced whole: its clusters all carry its ``group_error`` (meshoptimizer's absolute
deviation of the positions and, weighted by :data:`NORMAL_WEIGHT`, of the normals, plus its inputs'
largest, world units) and ``group_boxes`` (around its inputs' groups'),
and its inputs all carry it as their ``parent``. Errors and boxes only grow up the DAG, so a group
shows on screen at least its inputs' errors from any eye, and drawing every cluster whose own group
fits a bound and whose parent does not (:func:`node.culling.lod.lod_cut`) covers the model exactly
once; the clusters of groups drawn side by side meet on locked borders: no cracks where the model has
none. The coarse levels index the scene's own vertices: they add indices only (about two thirds of
the full level's when each level keeps 40 %).

The simplifier is meshoptimizer because it locks a submesh's border. Its calls release the GIL:
a level's groups are simplified on :data:`WORKERS` threads.

A batch is marked **closed** (``batch_closed``) when its faces bound solids, facing outwards: every
edge (positions welded) is met as often in one direction as in the other, and the signed volume is
positive (:func:`closed_surface`). From outside such a batch its back faces are always behind its
front ones, so a moving frame may leave them out (:class:`node.gl.renderer.TileRenderer`).
"""

from __future__ import annotations

import ctypes
import heapq
import itertools
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cache, partial
from pathlib import Path
from typing import Any

import numpy as np

from node.scene.cache import CacheError, Progress, read_arrays, write_arrays
from node.scene.chunks import SceneChunks
from node.scene.data import SceneData
from node.scene.octree import morton_codes

#: Faces of a leaf (runs of whole chunks of about this many) and of a coarse cluster.
CLUSTER_FACES = 2048
#: Faces of a part of a coarse cluster: a run of its triangles (in Morton order) with a box of its
#: own, which a tile's culling tests (a coarse cluster covers far more of the screen than a chunk
#: of full detail; culled whole, it was drawn by every tile it touched). The 24.8M model at 1 px,
#: three tiles' coarse triangles over the whole frame's: 2048 (whole clusters) +20 %, 512 +11 %,
#: 256 +8 %, 128 +6 %, 64 +5 % (and 14 % more draw commands than 256).
PART_FACES = 128
#: Faces a group gathers (neighbouring clusters of a level, about this many in all).
GROUP_FACES = 8 * CLUSTER_FACES
#: The fraction of its faces a group's simplification aims at. Finer steps than a quarter: a bound
#: falls between two levels' errors and the finer of them is drawn, so with coarser steps a frame
#: draws more than its bound needs. The 24.8M model from three orbit cameras at 1280x720: 0.25 drew
#: 1.19-1.29M triangles at 2 px (39.2-42.3 dB from full detail) and 0.58-0.81M at 3 px (34.9-38.6 dB),
#: 0.4 drew 0.61-0.66M at 2 px (38.3-40.5 dB); 0.5 did no better than 0.4 and costs the full level's
#: indices again (over the +40 % memory bound).
KEEP = 0.4
#: A group's error is at most this many times its inputs' largest (it keeps more faces instead).
GROWTH = 8.0
#: A group is made only when its simplification keeps at most this fraction of its faces.
MAX_KEPT = 0.7
#: Batches of fewer faces than this get no levels (nothing to gain).
MIN_FACES = GROUP_FACES
#: Levels at most (each keeps at most :data:`MAX_KEPT`: far more than a batch needs).
MAX_LEVELS = 48
#: Bytes a scan's levels take a triangle of its full level, about (the coarse levels' indices, two
#: thirds of the full level's 12, and their tables): the bunny 7.9, the 99M-triangle Pan model 7.7.
#: What a node expects them to need before it builds them (:class:`node.gl.worker.GLWorker`).
BYTES_PER_TRIANGLE = 8
#: How much a normal turned counts in a group's error: a turn of ``t`` (the difference of unit
#: normals) counts as ``NORMAL_WEIGHT · t`` times the group's extent (meshoptimizer's attribute
#: metric, the weight of its own cluster-LOD example). Without it a far view of a scan drew its
#: coarse levels with the fine level's noisy vertex normals: shading, not outlines, cost the PSNR.
NORMAL_WEIGHT = 0.5
#: The format of the levels' entry (:func:`write_lod`): another is built again, never read.
LOD_FORMAT = 7
WORKERS = max(1, min(4, os.cpu_count() or 1))
#: Corners whose clusters' adjacency is found at a time.
BLOCK_CORNERS = 1 << 23
#: Faces whose edges :func:`closed_surface` counts at a time, and the buckets it counts them in.
BLOCK_FACES = 1 << 22
EDGE_BITS = 22


@dataclass(frozen=True, eq=False)
class LodTree:
    """The levels of a scene: L leaves, G groups and N coarse clusters (a DAG).

    Leaves: ``leaf_first_chunk`` / ``leaf_end_chunk`` (L,) int64 the scene chunks each covers (in
    order); ``leaf_group`` (L,) int64 the group that simplified it (−1: none).

    Groups: ``group_level`` (G,) int64 (1: made of leaves); ``group_error`` (G,) float32 world units;
    ``group_boxes`` (G, 2, 3) float32 [min, max], around its inputs' groups' boxes.

    Clusters: ``batch`` (N,) int64; ``own`` (N,) int64 the group that made it; ``parent`` (N,) int64
    the group that simplified it in turn (−1: none); ``boxes`` (N, 2, 3) float32 around its
    triangles; ``index_bounds`` (N + 1,) int64: cluster n is ``indices[index_bounds[n]:index_bounds[n
    + 1]]``, uint32 batch-local like the scene's own indices, batch by batch, its triangles in Morton
    order. Parts: ``cluster_parts`` (N + 1,) int64: cluster n's parts are ``cluster_parts[n]`` …
    ``cluster_parts[n + 1] − 1``; ``part_bounds`` (Q + 1,) int64: part q is ``indices[part_bounds[q]:
    part_bounds[q + 1]]`` (:data:`PART_FACES` triangles, a cluster's last fewer); ``part_boxes``
    (Q, 2, 3) float32 around its triangles. ``share_cluster``,
    ``share_chunk``, ``share_triangles`` (P,) int64: how many of a cluster's triangles start at a
    vertex of each chunk (where its triangles lie, for :func:`group_levels`).

    Batches: ``batch_closed`` (B,) bool: its faces bound solids, facing outwards (:func:`closed_surface`;
    False for a batch without levels).
    """

    leaf_first_chunk: np.ndarray
    leaf_end_chunk: np.ndarray
    leaf_group: np.ndarray
    group_level: np.ndarray
    group_error: np.ndarray
    group_boxes: np.ndarray
    batch: np.ndarray
    own: np.ndarray
    parent: np.ndarray
    boxes: np.ndarray
    index_bounds: np.ndarray
    indices: np.ndarray
    cluster_parts: np.ndarray
    part_bounds: np.ndarray
    part_boxes: np.ndarray
    share_cluster: np.ndarray
    share_chunk: np.ndarray
    share_triangles: np.ndarray
    batch_closed: np.ndarray

    @property
    def node_count(self) -> int:
        """Coarse clusters."""
        return int(self.batch.size)

    @property
    def nbytes(self) -> int:
        return int(sum(np.asarray(getattr(self, name)).nbytes for name in self.__dataclass_fields__))

    @property
    def triangles(self) -> np.ndarray:
        """(N,) int64 triangles of each cluster."""
        return np.diff(self.index_bounds) // 3

    @property
    def level(self) -> np.ndarray:
        """(N,) int64 each cluster's level (its group's)."""
        return self.group_level[self.own]

    @property
    def error(self) -> np.ndarray:
        """(N,) float32 each cluster's error (its group's)."""
        return self.group_error[self.own]

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(getattr(self, name)) for name in self.__dataclass_fields__}


def _leaves(face_counts: np.ndarray, first: int, end: int) -> np.ndarray:
    """Chunk bounds (K + 1,) of runs of chunks [first, end) with about :data:`CLUSTER_FACES` faces each."""
    running = np.cumsum(face_counts[first:end])
    cuts = np.searchsorted(running, np.arange(CLUSTER_FACES, running[-1], CLUSTER_FACES), side="left") + 1
    return np.unique(np.concatenate(([0], cuts, [end - first]))) + first


def _position_keys(positions: np.ndarray) -> np.ndarray:
    """(V,) uint64 a hash of each of ``positions`` (V, 3) float32 bits: equal positions, equal keys."""
    keys = np.empty(len(positions), np.uint64)
    for first in range(0, len(positions), BLOCK_FACES):
        bits = np.ascontiguousarray(positions[first:first + BLOCK_FACES], np.float32).view(np.uint32).astype(np.uint64)
        keys[first:first + BLOCK_FACES] = (bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)) \
            ^ (bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) ^ (bits[:, 2] * np.uint64(0x165667B19E3779F9))
    return keys


def _weld(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(weld (V,) int64 the id of each vertex's position, first (W,) int64 the first vertex at each):
    a scan split at texture or normal seams has borders everywhere, which would all be locked."""
    _, first, weld = np.unique(_position_keys(positions), return_index=True, return_inverse=True)
    if not np.array_equal(positions[first[weld.reshape(-1)]], positions):   # a hash collision: exact
        rows = np.ascontiguousarray(positions, np.float32).view(np.dtype((np.void, 12))).reshape(-1)
        _, first, weld = np.unique(rows, return_index=True, return_inverse=True)
    return weld.reshape(-1).astype(np.int64), first.astype(np.int64)


def closed_surface(faces: np.ndarray, weld: np.ndarray, positions: np.ndarray) -> bool:
    """Whether ``faces`` (F, 3) over ``positions`` (V, 3) bound solids facing outwards (counter-clockwise
    seen from outside): with positions welded (``weld`` (V,) integers, equal for the vertices at one
    position: :func:`_weld`'s ids or :func:`_position_keys`), every edge is met as often from a to b
    as from b to a, and the signed volume is positive. An edge's signed count is summed, weighted by a
    hash of it, into one of 2^:data:`EDGE_BITS` buckets (exact integers in float64): an unmatched edge
    leaves its bucket non-zero (another cancelling it exactly is a 1 in 2²⁰ chance)."""
    sums = np.zeros(1 << EDGE_BITS)
    volume = 0.0
    for first in range(0, len(faces), BLOCK_FACES):
        ids = np.asarray(weld)[faces[first:first + BLOCK_FACES]].astype(np.uint64)
        a, b = ids.reshape(-1), np.roll(ids, -1, axis=1).reshape(-1)
        key = (np.minimum(a, b) * np.uint64(0xD6E8FEB86659FD93)) ^ np.maximum(a, b)
        bucket = (key * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - EDGE_BITS)
        weight = ((key * np.uint64(0xC2B2AE3D27D4EB4F)) >> np.uint64(44)).astype(np.float64) + 1.0
        sign = (b > a).astype(np.float64) - (b < a)
        sums += np.bincount(bucket.astype(np.int64), sign * weight, 1 << EDGE_BITS)
        corners = np.asarray(positions)[faces[first:first + BLOCK_FACES]].astype(np.float64)
        volume += float(np.einsum("ij,ij->", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])))
    return not sums.any() and volume > 0.0


def closed_batches(scene: SceneData) -> np.ndarray:
    """(B,) bool: which batches of ``scene`` bound solids facing outwards (:func:`closed_surface`, the
    positions keyed by their hash). What a sort-last share's levels mark closed: a share of a closed
    batch is not closed by itself (:func:`node.scene.ingest.cached_levels`)."""
    closed = np.zeros(len(scene.batches), bool)
    for number, batch in enumerate(scene.batches):
        positions = np.asarray(batch.positions)
        faces = np.asarray(batch.faces).reshape(-1, 3)
        closed[number] = bool(len(faces)) and closed_surface(faces, _position_keys(positions), positions)
    return closed


def _simplify(indices: np.ndarray, limit: float, positions: np.ndarray,
              normals: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """(indices, absolute error) of ``indices`` (3T,) over ``positions`` (V, 3) float32 simplified to
    about :data:`KEEP` of them, the submesh's border locked, or fewer where the error would pass
    ``limit`` (world units). With ``normals`` (V, 3) the error counts how far the normals turn too
    (:data:`NORMAL_WEIGHT`)."""
    import meshoptimizer

    used, local = np.unique(indices, return_inverse=True)
    local = local.reshape(-1).astype(np.uint32)
    out = np.empty_like(local)
    error = np.zeros(1, np.float32)
    points = np.ascontiguousarray(positions[used], np.float32)
    target = int(len(local) * KEEP) // 3 * 3
    options = meshoptimizer.SIMPLIFY_LOCK_BORDER | meshoptimizer.SIMPLIFY_ERROR_ABSOLUTE
    if normals is None:
        kept = meshoptimizer.simplify(out, local, points, target_index_count=target, target_error=limit,
                                      options=options, result_error=error)
    else:
        attributes = np.ascontiguousarray(normals[used], np.float32)
        weights = np.full(3, NORMAL_WEIGHT, np.float32)
        kept = _simplify_with_attributes()(
            out.ctypes.data, local.ctypes.data, local.size, points.ctypes.data, len(points), 12,
            attributes.ctypes.data, 12, weights.ctypes.data, 3, None, target, limit, options, error.ctypes.data)
    return used[out[:kept]].astype(np.uint32), float(error[0])


@cache
def _simplify_with_attributes() -> Any:
    """meshoptimizer's ``meshopt_simplifyWithAttributes``, typed here (its Python wrapper passes the
    target error as an untyped float, which ctypes refuses), from a handle of our own on its library."""
    from meshoptimizer import _loader

    function = ctypes.CDLL(_loader.lib._name).meshopt_simplifyWithAttributes
    pointer, size = ctypes.c_void_p, ctypes.c_size_t
    function.argtypes = [pointer, pointer, size, pointer, size, size, pointer, size, pointer, size, pointer, size,
                         ctypes.c_float, ctypes.c_uint, pointer]
    function.restype = size
    return function


def _split(indices: np.ndarray, positions: np.ndarray) -> list[np.ndarray]:
    """``indices`` (3T,) cut into clusters of about :data:`CLUSTER_FACES` triangles: runs of them in
    the Morton order of their centres."""
    parts = max(1, -(-(indices.size // 3) // CLUSTER_FACES))
    triangles = indices.reshape(-1, 3)
    centres = positions[triangles].mean(axis=1)
    lo = centres.min(axis=0)
    side = max(float((centres.max(axis=0) - lo).max()), 1e-30)   # a cube: flat parts too
    order = np.argsort(morton_codes(centres, lo, lo + side, 10), kind="stable")
    cuts = np.linspace(0, len(triangles), parts + 1).round().astype(np.int64)
    return [triangles[order[a:b]].reshape(-1) for a, b in itertools.pairwise(cuts)]


def _adjacency(clusters: list[np.ndarray], weld: np.ndarray, welded: int) -> tuple[np.ndarray, np.ndarray]:
    """(pairs (P, 2) int64 of clusters that share border vertices, a < b; weights (P,) int64 their
    shared corners) of ``clusters`` (index arrays over vertices that ``weld`` maps to ``welded`` ids)."""
    low, high = np.full(welded, -1, np.int64), np.full(welded, -1, np.int64)
    blocks, start, size = [], 0, 0
    for number, cluster in enumerate(clusters):
        size += cluster.size
        if size >= BLOCK_CORNERS or number == len(clusters) - 1:
            blocks.append((start, number + 1))
            start, size = number + 1, 0

    def corners(first: int, end: int) -> tuple[np.ndarray, np.ndarray]:
        ids = np.concatenate(clusters[first:end])
        owner = np.repeat(np.arange(first, end), [c.size for c in clusters[first:end]])
        return weld[ids], owner

    for first, end in blocks:   # clusters in order: the last writer of a vertex is its highest cluster
        vertex, owner = corners(first, end)
        high[vertex] = owner
    for first, end in reversed(blocks):
        vertex, owner = corners(first, end)
        low[vertex[::-1]] = owner[::-1]
    keys = []
    for first, end in blocks:
        vertex, _ = corners(first, end)
        a, b = low[vertex], high[vertex]
        shared = a != b
        keys.append(a[shared] * len(clusters) + b[shared])
    pairs, weights = np.unique(np.concatenate(keys), return_counts=True)
    return np.stack([pairs // len(clusters), pairs % len(clusters)], axis=1), weights


def _partition(sizes: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> list[list[int]]:
    """Groups of clusters with ``sizes`` (C,) faces: the smallest group merges with the neighbour it
    shares most border with (``pairs`` (P, 2), ``weights`` (P,)) while they stay within
    :data:`GROUP_FACES` faces."""
    neighbours: list[dict[int, int]] = [{} for _ in range(len(sizes))]
    for (a, b), weight in zip(pairs.tolist(), weights.tolist(), strict=True):
        neighbours[a][b] = neighbours[a].get(b, 0) + weight
        neighbours[b][a] = neighbours[b].get(a, 0) + weight
    size = [int(s) for s in sizes]
    members: list[list[int] | None] = [[c] for c in range(len(sizes))]
    heap = [(s, c) for c, s in enumerate(size)]
    heapq.heapify(heap)
    done: list[list[int]] = []
    while heap:
        got, group = heapq.heappop(heap)
        listed = members[group]
        if listed is None or got != size[group]:
            continue
        fitting = [(weight, -size[other], other) for other, weight in neighbours[group].items()
                   if members[other] is not None and size[group] + size[other] <= GROUP_FACES]
        if not fitting:
            done.append(listed)
            members[group] = None
            continue
        _, _, other = max(fitting)
        merged = members[other]
        assert merged is not None
        listed.extend(merged)
        members[other] = None
        size[group] += size[other]
        for far, weight in neighbours[other].items():
            if far != group:
                neighbours[far].pop(other)
                neighbours[far][group] = neighbours[far].get(group, 0) + weight
                neighbours[group][far] = neighbours[group].get(far, 0) + weight
        neighbours[group].pop(other)
        neighbours[other] = {}
        heapq.heappush(heap, (size[group], group))
    return done


class _Builder:
    """The DAG's groups and clusters as they are made, batch by batch (:func:`build_lod`)."""

    def __init__(self) -> None:
        self.group_level: list[int] = []
        self.group_error: list[float] = []
        self.group_boxes: list[np.ndarray] = []
        self.batch: list[int] = []
        self.own: list[int] = []
        self.parent: list[int] = []
        self.indices: list[np.ndarray] = []
        self.leaf_group: list[np.ndarray] = []
        self.leaf_bounds: list[np.ndarray] = []
        self.shares: list[np.ndarray] = []
        self.closed: list[int] = []

    def batch_levels(self, number: int, scene: SceneData, pool: ThreadPoolExecutor, progress: Progress) -> None:
        """Build the levels of batch ``number`` of ``scene``."""
        chunks, batch = scene.chunks, scene.batches[number]
        first, end = int(chunks.batch_bounds[number]), int(chunks.batch_bounds[number + 1])
        bounds = _leaves(chunks.face_counts, first, end)
        positions = np.asarray(batch.positions, np.float32)
        normals = None if batch.normals is None else np.asarray(batch.normals)
        weld, first_vertex = _weld(positions)
        canonical = first_vertex[weld].astype(np.uint32)   # each vertex as the first at its position
        faces = np.asarray(batch.faces).reshape(-1)
        if closed_surface(faces.reshape(-1, 3), weld, positions):
            self.closed.append(number)
        base = int(chunks.index_bounds[first])
        corner = chunks.index_bounds[bounds] - base
        leaf_group = np.full(bounds.size - 1, -1, np.int64)
        # The level below: each cluster's indices, error, box (its group's) and id (≥ 0: a coarse
        # cluster, < 0: −1 − its leaf in this batch).
        below = [canonical[faces[a:b]] for a, b in itertools.pairwise(corner)]
        errors = [0.0] * len(below)
        boxes = [_box(chunks.boxes, int(a), int(b)) for a, b in itertools.pairwise(bounds)]
        ids = [-1 - leaf for leaf in range(len(below))]
        first_cluster = len(self.own)
        for level in range(1, MAX_LEVELS + 1):
            if len(below) < 2:
                break
            pairs, weights = _adjacency(below, weld, first_vertex.size)
            groups = _partition(np.array([c.size // 3 for c in below]), pairs, weights)
            inputs = [np.concatenate([below[m] for m in group]) for group in groups]
            # A group stops short of KEEP rather than pass GROWTH times its inputs' error (one
            # straddling separate pieces of a model would otherwise collapse them far).
            limits = [GROWTH * max(errors[m] for m in group) or float(np.finfo(np.float32).max) for group in groups]
            results = list(pool.map(partial(_simplify, positions=positions, normals=normals), inputs, limits))
            above: list[tuple[np.ndarray, float, np.ndarray, int]] = []
            made = 0
            for group, source, (kept, error) in zip(groups, inputs, results, strict=True):
                if kept.size == 0 or kept.size > MAX_KEPT * source.size:   # left for the next level
                    above.extend((below[m], errors[m], boxes[m], ids[m]) for m in group)
                    continue
                made += 1
                error += max(errors[m] for m in group)
                box = np.stack([np.min([boxes[m][0] for m in group], axis=0),
                                np.max([boxes[m][1] for m in group], axis=0)])
                made_by = self._group(level, error, box)
                for m in group:
                    if ids[m] < 0:
                        leaf_group[-1 - ids[m]] = made_by
                    else:
                        self.parent[ids[m]] = made_by
                for part in _split(kept, positions):
                    above.append((part, error, box, len(self.own)))
                    self.batch.append(number)
                    self.own.append(made_by)
                    self.parent.append(-1)
                    self.indices.append(part)
            progress(min(0.99, level / 12), f"levels of detail: level {level}, {made} groups of batch {batch.name}")
            if made == 0:
                break
            below, errors, boxes, ids = (list(column) for column in zip(*above, strict=True))
        self.leaf_bounds.append(bounds)
        self.leaf_group.append(leaf_group)
        self.shares.append(_shares(self.indices[first_cluster:], first_cluster, faces, weld, bounds, chunks))

    def _group(self, level: int, error: float, box: np.ndarray) -> int:
        """A new group's id."""
        self.group_level.append(level)
        self.group_error.append(error)
        self.group_boxes.append(box)
        return len(self.group_level) - 1

    def tree(self, positions_of: list[np.ndarray]) -> LodTree:
        """The DAG built; ``positions_of`` each batch's positions (V, 3) (for the parts' and clusters' boxes)."""
        counts = np.array([part.size for part in self.indices], np.int64)
        index_bounds = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
        indices = np.concatenate(self.indices) if self.indices else np.zeros(0, np.uint32)
        batch = np.array(self.batch, np.int64)
        cluster_parts, part_bounds = _parts(index_bounds)
        part_batch = np.repeat(batch, np.diff(cluster_parts))
        part_boxes = np.zeros((part_batch.size, 2, 3), np.float32)
        for number, positions in enumerate(positions_of):
            mine = np.flatnonzero(part_batch == number)
            if mine.size:
                a, b = part_bounds[mine[0]], part_bounds[mine[-1] + 1]
                corners = positions[indices[a:b]]
                starts = part_bounds[mine] - a
                part_boxes[mine, 0] = np.minimum.reduceat(corners, starts, axis=0)
                part_boxes[mine, 1] = np.maximum.reduceat(corners, starts, axis=0)
        boxes = np.zeros((batch.size, 2, 3), np.float32)
        if batch.size:
            boxes[:, 0] = np.minimum.reduceat(part_boxes[:, 0], cluster_parts[:-1], axis=0)
            boxes[:, 1] = np.maximum.reduceat(part_boxes[:, 1], cluster_parts[:-1], axis=0)
        empty = np.zeros(0, np.int64)
        shares = np.concatenate(self.shares, axis=1) if self.shares else np.zeros((3, 0), np.int64)
        return LodTree(
            leaf_first_chunk=np.concatenate([b[:-1] for b in self.leaf_bounds]) if self.leaf_bounds else empty,
            leaf_end_chunk=np.concatenate([b[1:] for b in self.leaf_bounds]) if self.leaf_bounds else empty,
            leaf_group=np.concatenate(self.leaf_group) if self.leaf_group else empty,
            group_level=np.array(self.group_level, np.int64), group_error=np.array(self.group_error, np.float32),
            group_boxes=np.array(self.group_boxes, np.float32).reshape(-1, 2, 3),
            batch=batch, own=np.array(self.own, np.int64), parent=np.array(self.parent, np.int64), boxes=boxes,
            index_bounds=index_bounds, indices=indices.astype(np.uint32),
            cluster_parts=cluster_parts, part_bounds=part_bounds, part_boxes=part_boxes,
            share_cluster=shares[0], share_chunk=shares[1], share_triangles=shares[2],
            batch_closed=np.isin(np.arange(len(positions_of)), self.closed))


def _parts(index_bounds: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cluster_parts (N + 1,), part_bounds (Q + 1,)) int64: the clusters of ``index_bounds`` (N + 1,)
    cut into parts of :data:`PART_FACES` triangles from each cluster's start (its last part fewer)."""
    triangles = np.diff(index_bounds) // 3
    counts = np.maximum(1, -(-triangles // PART_FACES))
    cluster_parts = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
    cluster = np.repeat(np.arange(triangles.size), counts)
    within = np.arange(int(cluster_parts[-1])) - cluster_parts[cluster]
    starts = index_bounds[cluster] + 3 * PART_FACES * within
    return cluster_parts, np.append(starts, index_bounds[-1]).astype(np.int64)


def _shares(clusters: list[np.ndarray], first_cluster: int, faces: np.ndarray, weld: np.ndarray,
            bounds: np.ndarray, chunks: SceneChunks) -> np.ndarray:
    """(3, P) int64 rows cluster, chunk, triangles: how many of ``clusters``' (numbered from
    ``first_cluster``) triangles start at a position of each chunk of the batch (``faces`` (3F,)
    its indices, chunks [bounds[0], bounds[-1]))."""
    if not clusters:
        return np.zeros((3, 0), np.int64)
    first, end = int(bounds[0]), int(bounds[-1])
    chunk_of_face = np.repeat(np.arange(first, end, dtype=np.int32), chunks.face_counts[first:end])
    chunk_at = np.zeros(int(weld.max()) + 1, np.int32)
    for corner in range(3):
        chunk_at[weld[faces[corner::3]]] = chunk_of_face
    starts = np.concatenate([c[0::3] for c in clusters])
    owner = np.repeat(np.arange(first_cluster, first_cluster + len(clusters)), [c.size // 3 for c in clusters])
    keys = owner * (end + 1) + chunk_at[weld[starts]]
    pairs, counts = np.unique(keys, return_counts=True)
    return np.stack([pairs // (end + 1), pairs % (end + 1), counts]).astype(np.int64)


def _box(boxes: np.ndarray, first: int, end: int) -> np.ndarray:
    return np.stack([boxes[first:end, 0].min(axis=0), boxes[first:end, 1].max(axis=0)]).astype(np.float64)


def build_lod(scene: SceneData, progress: Progress) -> LodTree:
    """The levels of ``scene``'s non-blended batches of at least :data:`MIN_FACES` faces."""
    builder = _Builder()
    positions_of = []
    pool = ThreadPoolExecutor(WORKERS)
    try:
        for number, batch in enumerate(scene.batches):
            positions_of.append(np.asarray(batch.positions, np.float32))
            if batch.alpha_mode != "BLEND" and batch.triangle_count >= MIN_FACES:
                builder.batch_levels(number, scene, pool, progress)
    finally:
        pool.shutdown()
    return builder.tree(positions_of)


#: A scene's primitive groups' levels: errors, triangles and boxes (:func:`group_levels`).
GroupLevels = tuple[np.ndarray, np.ndarray, np.ndarray]


def group_levels(tree: LodTree, group_starts: np.ndarray, face_counts: np.ndarray,
                 chunk_boxes: np.ndarray) -> GroupLevels:
    """What the coordinator's balancers predict with (issue 32): for each primitive group (runs of
    chunks starting at ``group_starts`` (K,); chunk faces ``face_counts`` (C,), chunk boxes
    ``chunk_boxes`` (C, 2, 3)) and each level k of 0 (full detail) … L: its ``triangles`` (K, L + 1)
    float64 when every group of level ≤ k is drawn instead of its inputs (a coarse cluster counts
    where its triangles start), the ``errors`` (K, L + 1) float64 (world units) and ``boxes``
    (K, L + 1, 6) float64 (x0, y0, z0, x1, y1, z1) of the level-k group that made most of those
    triangles (the level below's where none did; level 0: error 0, the group's own box). Errors
    only grow and triangles only shrink from a level to the next."""
    chunk_count = int(face_counts.size)
    group_starts = np.asarray(group_starts, np.int64)
    count = group_starts.size
    primitive = np.searchsorted(group_starts, np.arange(chunk_count), side="right") - 1
    # The level at which each chunk stops being drawn at full detail (a large number: never).
    never = np.iinfo(np.int64).max
    leaf_until = np.where(tree.leaf_group >= 0, tree.group_level[np.maximum(tree.leaf_group, 0)], never)
    until = np.full(chunk_count, never, np.int64)
    lengths = tree.leaf_end_chunk - tree.leaf_first_chunk
    offsets = np.arange(int(lengths.sum())) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    until[np.repeat(tree.leaf_first_chunk, lengths) + offsets] = np.repeat(leaf_until, lengths)
    cluster_level = tree.level
    cluster_until = np.where(tree.parent >= 0, tree.group_level[np.maximum(tree.parent, 0)], never)
    share_group = primitive[tree.share_chunk]
    share_level = cluster_level[tree.share_cluster]
    flat_boxes = chunk_boxes.reshape(-1, 6).astype(np.float64)
    box = np.concatenate([np.minimum.reduceat(flat_boxes[:, :3], group_starts, axis=0),
                          np.maximum.reduceat(flat_boxes[:, 3:], group_starts, axis=0)], axis=1)
    error = np.zeros(count)
    levels = int(tree.group_level.max()) + 1 if tree.group_level.size else 1
    errors, triangles, boxes = [], [], []
    for level in range(levels):
        drawn = (cluster_level <= level) & (cluster_until > level)
        share = drawn[tree.share_cluster]
        triangles.append(np.bincount(primitive, face_counts * (until > level), count).astype(np.float64)
                         + np.bincount(share_group[share], tree.share_triangles[share], count))
        # The group of this level that made most of a primitive group's triangles speaks for it.
        made = np.flatnonzero(share_level == level)
        if made.size:
            made = made[np.lexsort((-tree.share_triangles[made], share_group[made]))]
            head = made[np.flatnonzero(np.diff(share_group[made], prepend=-1) != 0)]
            group = tree.own[tree.share_cluster[head]]
            error, box = error.copy(), box.copy()
            error[share_group[head]] = tree.group_error[group]
            box[share_group[head]] = tree.group_boxes[group].reshape(-1, 6)
        errors.append(error)
        boxes.append(box)
    errors_out = np.maximum.accumulate(np.stack(errors, axis=1), axis=1)
    triangles_out = np.minimum.accumulate(np.stack(triangles, axis=1), axis=1)
    return errors_out, triangles_out, np.stack(boxes, axis=1)


def lod_name(entry: str) -> str:
    """The name of the levels' entry of scene cache entry ``entry``."""
    return f"{entry}-lod{LOD_FORMAT}"


def write_lod(directory: Path, tree: LodTree) -> int:
    """Write ``tree`` as the entry ``directory`` (atomically); returns its bytes."""
    return write_arrays(directory, tree.arrays(), {"format": LOD_FORMAT, "nodes": tree.node_count,
                                                    "triangles": int(tree.triangles.sum())})


def read_lod(directory: Path, verify: bool = True) -> LodTree:
    """The levels of the entry ``directory`` (arrays mapped); raises CacheError."""
    _, arrays = read_arrays(directory, verify, LOD_FORMAT)
    try:
        return LodTree(**{name: (arrays[name] if name == "indices" else np.array(arrays[name]))
                          for name in LodTree.__dataclass_fields__})
    except (KeyError, TypeError) as exc:
        raise CacheError(f"{directory.name}: inconsistent levels ({exc})") from None
