"""Levels of detail (issue 32): a tree of coarser versions of a scene's big batches, built once per
scene cache entry and stored beside it. No GL here; the per-frame choice is :mod:`node.culling.lod`.

A batch's chunks, in their Morton order, are cut into **leaves** of about :data:`LEAF_FACES` faces
(runs of whole chunks: neighbours in space). Every :data:`FANOUT` consecutive leaves get a parent:
their faces simplified together to about a quarter (meshoptimizer's ``simplify``, the group's border
locked), then every :data:`FANOUT` parents a grandparent simplified from the parents' faces, and so
on up to one root a batch, or until a level no longer halves its input (its locked border left
nothing to remove). The coarse levels index the scene's own vertices: they add indices only (about
a third of the full level's when every level quarters its input).

Every node's border is its region's border at full detail, locked at every level, so the nodes of
any cut of the tree — any mix of levels — meet edge to edge: no cracks where the model has none.
Each node's ``error`` is meshoptimizer's absolute deviation of its simplification plus its children's
largest error, in world units: it only grows towards the root, as a node's box only grows, so the
error a node shows on screen from any eye is at least any of its descendants' (the cut is then
found level-free, :func:`node.culling.lod.lod_cut`).

The simplifier is meshoptimizer because it locks a submesh's border (a group's simplification must
keep the edges it shares with its neighbours; why not another: see the design notes). Its calls
release the GIL: the nodes of a level are simplified on :data:`WORKERS` threads.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from node.scene.cache import CacheError, Progress, read_arrays, write_arrays
from node.scene.data import SceneData

#: Faces of a leaf (runs of whole chunks of about this many faces).
LEAF_FACES = 2048
#: Children per node.
FANOUT = 4
#: A node is made only when its simplification keeps at most this fraction of its children's faces.
MAX_KEPT = 0.5
#: Batches of fewer faces than this get no levels (nothing to gain).
MIN_FACES = 2 * FANOUT * LEAF_FACES
#: The format of the levels' entry (:func:`write_lod`): another is built again, never read.
LOD_FORMAT = 1
WORKERS = max(1, min(4, os.cpu_count() or 1))


@dataclass(frozen=True, eq=False)
class LodTree:
    """The levels of a scene: L leaves and N coarse nodes.

    Leaves: ``leaf_chunks`` (L + 1,) int64: leaf i is the scene's chunks [leaf_chunks[i],
    leaf_chunks[i + 1]) (leaves cover the chunks of the batches with levels, in order: their first
    chunk, ``leaf_first_chunk`` (L,), and end ``leaf_end_chunk`` (L,)); ``leaf_parent`` (L,) int64
    the node over it (−1: none).

    Nodes: ``batch`` (N,) int64; ``level`` (N,) int64 (1 over leaves); ``parent`` (N,) int64 (−1: a
    root); ``error`` (N,) float32 world units; ``boxes`` (N, 2, 3) float32 [min, max];
    ``index_bounds`` (N + 1,) int64: node n is ``indices[index_bounds[n]:index_bounds[n + 1]]``,
    uint32 batch-local like the scene's own indices; ``chunk_first``/``chunk_end`` (N,) int64 the
    scene chunks its region covers.
    """

    leaf_first_chunk: np.ndarray
    leaf_end_chunk: np.ndarray
    leaf_parent: np.ndarray
    batch: np.ndarray
    level: np.ndarray
    parent: np.ndarray
    error: np.ndarray
    boxes: np.ndarray
    index_bounds: np.ndarray
    chunk_first: np.ndarray
    chunk_end: np.ndarray
    indices: np.ndarray

    @property
    def node_count(self) -> int:
        return int(self.batch.size)

    @property
    def nbytes(self) -> int:
        return int(sum(np.asarray(getattr(self, name)).nbytes for name in self.__dataclass_fields__))

    @property
    def triangles(self) -> np.ndarray:
        """(N,) int64 triangles of each node."""
        return np.diff(self.index_bounds) // 3

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: np.asarray(getattr(self, name)) for name in self.__dataclass_fields__}


def _leaves(face_counts: np.ndarray, first: int, end: int) -> np.ndarray:
    """Chunk bounds (K + 1,) of runs of chunks [first, end) with about :data:`LEAF_FACES` faces each."""
    running = np.cumsum(face_counts[first:end])
    cuts = np.searchsorted(running, np.arange(LEAF_FACES, running[-1], LEAF_FACES), side="left") + 1
    return np.unique(np.concatenate(([0], cuts, [end - first]))) + first


def _simplify(indices: np.ndarray, positions: np.ndarray) -> tuple[np.ndarray, float]:
    """(indices, absolute error) of ``indices`` (3T,) uint32 over ``positions`` (V, 3) float32
    simplified to about a quarter, the submesh's border locked.

    Vertices at one position are welded first (a scan split at texture or normal seams has borders
    everywhere, which would all be locked): the simplification sees the surface's own topology, and
    its triangles index the first of the vertices at each position."""
    import meshoptimizer

    used, local = np.unique(indices, return_inverse=True)
    points = np.ascontiguousarray(positions[used], np.float32)
    keys = points.view(np.dtype((np.void, points.dtype.itemsize * 3))).reshape(-1)
    _, first, welded = np.unique(keys, return_index=True, return_inverse=True)
    local = welded.reshape(-1)[local.reshape(-1)].astype(np.uint32)
    out = np.empty_like(local)
    error = np.zeros(1, np.float32)
    kept = meshoptimizer.simplify(
        out, local, np.ascontiguousarray(points[first]), target_index_count=len(local) // FANOUT,
        target_error=np.finfo(np.float32).max, options=meshoptimizer.SIMPLIFY_LOCK_BORDER |
        meshoptimizer.SIMPLIFY_ERROR_ABSOLUTE, result_error=error)
    return used[first[out[:kept]]].astype(np.uint32), float(error[0])


def build_lod(scene: SceneData, progress: Progress) -> LodTree:
    """The levels of ``scene``'s non-blended batches of at least :data:`MIN_FACES` faces."""
    chunks = scene.chunks
    face_counts = chunks.face_counts
    leaf_bounds: list[np.ndarray] = []
    nodes: list[dict[str, Any]] = []
    leaf_parent: list[np.ndarray] = []
    pool = ThreadPoolExecutor(WORKERS)
    total = sum(b.triangle_count for b in scene.batches)
    done = 0
    try:
        for number, batch in enumerate(scene.batches):
            if batch.alpha_mode == "BLEND" or batch.triangle_count < MIN_FACES:
                continue
            first, end = int(chunks.batch_bounds[number]), int(chunks.batch_bounds[number + 1])
            bounds = _leaves(face_counts, first, end)
            leaf_bounds.append(bounds)
            parents = np.full(bounds.size - 1, -1, np.int64)
            positions = np.asarray(batch.positions, np.float32)
            batch_index_first = int(chunks.index_bounds[first])
            # The level below, as (chunk first, chunk end, indices, error, node id or leaf id) per member.
            below = [(int(bounds[i]), int(bounds[i + 1]),
                      np.asarray(batch.faces).reshape(-1)[int(chunks.index_bounds[bounds[i]]) - batch_index_first:
                                                          int(chunks.index_bounds[bounds[i + 1]]) - batch_index_first],
                      0.0, -1 - i) for i in range(bounds.size - 1)]
            level = 0
            while len(below) > 1:
                level += 1
                groups = [below[i:i + FANOUT] for i in range(0, len(below), FANOUT)]
                inputs = [np.concatenate([member[2] for member in group]) for group in groups]
                results = list(pool.map(partial(_simplify, positions=positions), inputs))
                above = []
                for group, source, (kept, error) in zip(groups, inputs, results, strict=True):
                    if len(group) < 2 or kept.size > MAX_KEPT * source.size:
                        continue
                    node = len(nodes)
                    error += max(member[3] for member in group)
                    box = _box(chunks.boxes, group[0][0], group[-1][1])
                    nodes.append({"batch": number, "level": level, "error": error, "box": box, "indices": kept,
                                  "chunk_first": group[0][0], "chunk_end": group[-1][1], "parent": -1})
                    for member in group:
                        if member[4] < 0:
                            parents[-1 - member[4]] = node
                        else:
                            nodes[member[4]]["parent"] = node
                    above.append((group[0][0], group[-1][1], kept, error, node))
                done += sum(source.size for source in inputs) // 3
                progress(min(0.99, done / max(1, total * 4 / 3)), f"levels of detail: level {level}, "
                                                                   f"{len(above)} nodes of batch {batch.name}")
                below = above
            leaf_parent.append(parents)
    finally:
        pool.shutdown()
    return _tree(leaf_bounds, leaf_parent, nodes)


def _box(boxes: np.ndarray, first: int, end: int) -> np.ndarray:
    return np.stack([boxes[first:end, 0].min(axis=0), boxes[first:end, 1].max(axis=0)])


def _tree(leaf_bounds: list[np.ndarray], leaf_parent: list[np.ndarray], nodes: list[dict[str, Any]]) -> LodTree:
    def column(name: str, dtype: type) -> np.ndarray:
        return np.array([node[name] for node in nodes], dtype)

    counts = np.array([node["indices"].size for node in nodes], np.int64)
    firsts = [b[:-1] for b in leaf_bounds]
    ends = [b[1:] for b in leaf_bounds]
    empty = np.zeros(0, np.int64)
    return LodTree(
        leaf_first_chunk=np.concatenate(firsts) if firsts else empty,
        leaf_end_chunk=np.concatenate(ends) if ends else empty,
        leaf_parent=np.concatenate(leaf_parent) if leaf_parent else empty,
        batch=column("batch", np.int64), level=column("level", np.int64), parent=column("parent", np.int64),
        error=column("error", np.float32),
        boxes=np.array([node["box"] for node in nodes], np.float32).reshape(-1, 2, 3),
        index_bounds=np.concatenate(([0], np.cumsum(counts))),
        chunk_first=column("chunk_first", np.int64), chunk_end=column("chunk_end", np.int64),
        indices=np.concatenate([node["indices"] for node in nodes]) if nodes else np.zeros(0, np.uint32))


def group_levels(tree: LodTree, group_starts: np.ndarray, face_counts: np.ndarray,
                 chunk_boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the coordinator's balancers predict with (issue 32): for each primitive group (runs of
    chunks starting at ``group_starts`` (K,); chunk faces ``face_counts`` (C,), chunk boxes
    ``chunk_boxes`` (C, 2, 3)) and each level k of 0 (full detail) … L: the group's ``errors``
    (K, L + 1) float64 (world units, the largest of the level's nodes over it), ``triangles``
    (K, L + 1) float64 (the level's nodes' triangles over it, shared out by faces) and ``boxes``
    (K, L + 1, 6) float64 (x0, y0, z0, x1, y1, z1 around those nodes: their error shows from the
    nearest of them). Where a level has no node over some chunks (a batch without levels, or whose
    tree stops lower), the level below stands."""
    chunk_count = int(face_counts.size)
    faces = np.concatenate(([0], np.cumsum(face_counts, dtype=np.int64)))
    group_starts = np.asarray(group_starts, np.int64)
    count = group_starts.size
    points = np.unique(np.concatenate([group_starts, [chunk_count], tree.chunk_first, tree.chunk_end]))
    points = points[points <= chunk_count]
    first, end = points[:-1], points[1:]
    segment_faces = (faces[end] - faces[first]).astype(np.float64)
    group = np.searchsorted(group_starts, first, side="right") - 1
    ratio, error = np.ones(first.size), np.zeros(first.size)
    box = np.concatenate([np.minimum.reduceat(chunk_boxes[:, 0], first, axis=0),
                          np.maximum.reduceat(chunk_boxes[:, 1], first, axis=0)], axis=1).astype(np.float64)
    node_faces = (faces[tree.chunk_end] - faces[tree.chunk_first]).astype(np.float64)
    node_boxes = tree.boxes.reshape(-1, 6).astype(np.float64)
    errors, triangles, boxes = [], [], []
    for level in range(int(tree.level.max()) + 1 if tree.node_count else 1):
        if level:
            nodes = np.flatnonzero(tree.level == level)
            nodes = nodes[np.argsort(tree.chunk_first[nodes])]
            at = np.searchsorted(tree.chunk_first[nodes], first, side="right") - 1
            covered = (at >= 0) & (first < tree.chunk_end[nodes[np.maximum(at, 0)]])
            chosen = nodes[at[covered]]
            ratio, error, box = ratio.copy(), error.copy(), box.copy()
            ratio[covered] = tree.triangles[chosen] / np.maximum(node_faces[chosen], 1.0)
            error[covered] = tree.error[chosen]
            box[covered] = node_boxes[chosen]
        triangles.append(np.bincount(group, segment_faces * ratio, count))
        most, low, high = np.zeros(count), np.full((count, 3), np.inf), np.full((count, 3), -np.inf)
        np.maximum.at(most, group, error)
        np.minimum.at(low, group, box[:, :3])
        np.maximum.at(high, group, box[:, 3:])
        errors.append(most)
        boxes.append(np.concatenate([low, high], axis=1))
    return np.stack(errors, axis=1), np.stack(triangles, axis=1), np.stack(boxes, axis=1)


def lod_name(entry: str) -> str:
    """The name of the levels' entry of scene cache entry ``entry``."""
    return f"{entry}-lod{LOD_FORMAT}"


def write_lod(directory: Path, tree: LodTree) -> int:
    """Write ``tree`` as the entry ``directory`` (atomically); returns its bytes."""
    return write_arrays(directory, tree.arrays(), {"format": LOD_FORMAT, "nodes": tree.node_count,
                                                    "triangles": int(tree.triangles.sum())})


def read_lod(directory: Path, verify: bool = True) -> LodTree:
    """The tree of the entry ``directory`` (arrays mapped); raises CacheError."""
    _, arrays = read_arrays(directory, verify, LOD_FORMAT)
    try:
        return LodTree(**{name: (arrays[name] if name == "indices" else np.array(arrays[name]))
                          for name in LodTree.__dataclass_fields__})
    except (KeyError, TypeError) as exc:
        raise CacheError(f"{directory.name}: inconsistent levels ({exc})") from None
