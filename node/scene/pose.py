"""What a frame's scene state (issue 11; seed 004: a frame's dynamic data, the same on every node)
asks of a node's renderer, per batch: the model matrix that moves it, whether it is drawn, and the
bounds that set the frame's near and far planes. No GL.

Geometry and its chunk boxes stay in world space at the base pose. A batch whose object has not
moved is culled per tile as before (seed 001) by the scene's chunk tree; a moved batch is left out
of that tree's cull and culled apart in its object's frame (:mod:`node.culling.objects`), or drawn
whole where a tile's chunks are listed (depth layers); a hidden batch is not drawn. Tiles and the whole
frame get the same matrices and the same near/far, so a tile stays identical to its region of the
whole frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.scene.chunks import DrawRuns
from node.scene.data import SceneData
from tessera.scene.state import SceneState


@dataclass(frozen=True, eq=False)
class ScenePose:
    """``bounds`` (2, 3) float64 world box of what is drawn (near/far come from it); per object
    ``models`` (N, 4, 4) float64 and ``normals`` (N, 3, 3) float64 (the inverse-transpose of the
    model's linear part), ``moved`` (N,) bool; per batch ``owner`` (B,) int64, ``skip`` (B,) bool
    (not drawn from the scene tree's cull: hidden, or moved and culled apart) and ``whole``, the
    moved visible batches in draw order, with their chunk and triangle totals."""

    bounds: np.ndarray
    models: np.ndarray
    normals: np.ndarray
    moved: np.ndarray
    owner: np.ndarray
    skip: np.ndarray
    whole: tuple[int, ...]
    whole_chunks: int
    whole_triangles: int

    @classmethod
    def of(cls, scene: SceneData, state: SceneState | None) -> ScenePose:
        """The pose of ``scene`` in ``state`` (None: the base pose, everything visible, unmoved)."""
        objects = scene.objects
        owner = np.array([b.owner for b in scene.batches], np.int64)
        count = len(objects)
        if state is None:
            models = np.broadcast_to(np.identity(4), (count, 4, 4)).copy()
            shown = np.ones(count, dtype=bool)
            bounds = scene.bounds
        else:
            models = objects.model_matrices(state)
            shown = objects.visibility(state)
            seen = objects.bounds(state)
            bounds = scene.bounds if seen is None else seen
        moved = ~(models == np.identity(4)).all(axis=(1, 2))
        normals = np.broadcast_to(np.identity(3), (count, 3, 3)).copy()
        if moved.any():
            normals[moved] = np.swapaxes(np.linalg.inv(models[moved, :3, :3]), 1, 2)
        whole_mask = moved[owner] & shown[owner]
        whole = tuple(int(b) for b in np.flatnonzero(whole_mask))
        chunk_counts = np.diff(scene.chunks.batch_bounds)
        return cls(bounds, models, normals, moved, owner, whole_mask | ~shown[owner], whole,
                   int(chunk_counts[whole_mask].sum()), sum(scene.batches[b].triangle_count for b in whole))

    def whole_runs(self, scene: SceneData, moved: DrawRuns | None) -> dict[int, list[tuple[int, int]]]:
        """The moved visible batches to draw, in draw order, each with its (first index, index count)
        runs: those of ``moved`` (a tile's cull of them; batches it culled away are left out), or
        every batch of :attr:`whole` in one run when ``moved`` is None."""
        if moved is None:
            return {batch: [self.index_range(scene, batch)] for batch in self.whole}
        first, count = moved.first.tolist(), moved.count.tolist()
        return {batch: list(zip(first[start:start + runs], count[start:start + runs], strict=True))
                for batch, start, runs in moved.batch_slices()}

    def index_range(self, scene: SceneData, batch: int) -> tuple[int, int]:
        """(first index, index count) of all of ``batch`` in the scene's index buffer."""
        chunks = scene.chunks
        first = int(chunks.index_bounds[chunks.batch_bounds[batch]])
        return first, int(chunks.index_bounds[chunks.batch_bounds[batch + 1]]) - first
