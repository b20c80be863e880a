"""Per-tile culling of moved objects (issue 11 item 5): geometry and chunk boxes stay in world space
at the base pose, and a moved batch is culled in that base frame with the tile's planes carried
into it. No GL.

A world plane p = (a, b, c, d) tests a world point y as p·[y, 1] ≥ 0; the moved batch puts its base
point x at y = M x (M its object's model matrix), so p·[M x, 1] = (Mᵀ p)·[x, 1]: the planes
``planes @ M`` cull the batch's unchanged chunk tree exactly (the p-/n-vertex box test needs no unit
normals), with no re-fitting per frame. Two levels:

- top level: each moved batch's box (the union of its chunk boxes) moved by M
  (:func:`tessera.scene.graph.transform_boxes`) against the world planes — a batch wholly outside
  is skipped, one wholly inside is kept whole, without its tree;
- the rest: the batch's own tree (:func:`node.culling.bvh.build_chunk_bvh` over its chunks, built
  the first time the batch moves, then kept) traversed with the carried planes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from node.culling.bvh import ChunkBVH, build_chunk_bvh, cull
from node.scene.chunks import DrawRuns, SceneChunks
from tessera.scene.graph import transform_boxes


class MovedCuller:
    """Culls moved batches of ``chunks`` per tile (see the module docstring); keeps one tree per
    batch that has moved."""

    def __init__(self, chunks: SceneChunks) -> None:
        self.chunks = chunks
        bounds = chunks.batch_bounds
        starts = bounds[:-1]
        boxes = chunks.boxes.astype(np.float64)
        #: (B, 2, 3) float64 base-pose box of each batch (the union of its chunk boxes)
        self.batch_boxes = np.stack([np.minimum.reduceat(boxes[:, 0], starts, axis=0),
                                     np.maximum.reduceat(boxes[:, 1], starts, axis=0)], axis=1)
        self._trees: dict[int, ChunkBVH] = {}

    def tree(self, batch: int) -> ChunkBVH:
        """The tree over ``batch``'s chunks (chunk ids relative to the batch's first chunk)."""
        found = self._trees.get(batch)
        if found is None:
            first, end = self.chunks.batch_bounds[batch], self.chunks.batch_bounds[batch + 1]
            found = self._trees[batch] = build_chunk_bvh(self.chunks.boxes[first:end])
        return found

    def cull(self, planes: np.ndarray | None, batches: Sequence[int], models: np.ndarray) -> DrawRuns:
        """The draw runs of the chunks of ``batches`` (sorted batch ids) moved by ``models`` (len,
        4, 4) float64 (each batch's object's model matrix) that are not wholly outside the world
        ``planes`` (6, 4) (None: no culling, every chunk of them), in batch order."""
        bounds = self.chunks.batch_bounds
        ids = np.asarray(batches, dtype=np.int64)
        if ids.size == 0:
            return self.chunks.runs(ids, ids)
        if planes is None:
            return self.chunks.runs(bounds[ids], bounds[ids + 1])
        planes = np.asarray(planes, dtype=np.float64)
        boxes = transform_boxes(self.batch_boxes[ids], models)
        center, extent = (boxes[:, 0] + boxes[:, 1]) * 0.5, (boxes[:, 1] - boxes[:, 0]) * 0.5
        distance = center @ planes[:, :3].T + planes[:, 3]                        # (n, 6)
        radius = extent @ np.abs(planes[:, :3]).T
        outside = (distance < -radius).any(axis=1)
        inside = (distance >= radius).all(axis=1)
        firsts, ends = [], []
        for number, batch in enumerate(ids.tolist()):
            if outside[number]:
                continue
            if inside[number]:
                firsts.append(bounds[batch:batch + 1])
                ends.append(bounds[batch + 1:batch + 2])
                continue
            result = cull(self.tree(batch), planes @ models[number])
            firsts.append(result.visible_first + bounds[batch])
            ends.append(result.visible_end + bounds[batch])
        if not firsts:
            empty = np.zeros(0, np.int64)
            return self.chunks.runs(empty, empty)
        return self.chunks.runs(np.concatenate(firsts), np.concatenate(ends))
