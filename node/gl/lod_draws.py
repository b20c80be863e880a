"""The GL side of a scene's levels of detail (issue 32): their index buffer and vertex arrays, and
per tile the indirect draw commands of the coarse clusters a frame's cut (:mod:`node.culling.lod`)
chose that touch the tile, nearest first (as :func:`node.culling.order.front_to_back` orders chunks:
a fragment behind what is drawn is not shaded), of each only the parts (runs of its triangles with
boxes of their own, :data:`node.scene.lod.PART_FACES`) that touch the tile. Use it on the GL thread
only."""

from __future__ import annotations

import moderngl
import numpy as np

from node.culling.frustum import frustum_planes_from_matrix
from node.culling.lod import LodCut, back_faces_hidden, boxes_in_frustum, lod_cut
from node.culling.tiles import indirect_commands
from node.gl.programs import ShaderPrograms
from node.scene.chunks import DrawRuns
from node.scene.data import SceneData
from node.scene.lod import LodTree
from node.scene.packing import gpu_indices
from node.scene.pages import release_pages
from tessera.geometry import Camera, Rect, near_far_from_bounds

#: Indices made global and copied to the GL at a time.
BLOCK_INDICES = 1 << 21


class LodDraws:
    """``tree``'s coarse clusters on ``shaders``' context: their indices (batch-local in the tree) with
    each batch's first vertex (``vertex_bounds`` (B + 1,)) added, in a buffer of their own, drawn
    through vertex arrays of every program over it."""

    def __init__(self, tree: LodTree, vertex_bounds: np.ndarray, shaders: ShaderPrograms, scene: SceneData) -> None:
        ctx: moderngl.Context = shaders.ctx
        self.tree = tree
        indices = tree.indices
        # The clusters come batch by batch: each batch's indices are one range of the buffer.
        batch_count = len(vertex_bounds) - 1
        first_node = np.searchsorted(tree.batch, np.arange(batch_count + 1), side="left")
        batch_index_bounds = tree.index_bounds[first_node]
        self.index_buffer = ctx.buffer(reserve=max(4, indices.nbytes))
        scratch = np.empty(BLOCK_INDICES, np.uint32)
        for first in range(0, len(indices), BLOCK_INDICES):
            end = min(first + BLOCK_INDICES, len(indices))
            self.index_buffer.write(gpu_indices(indices, batch_index_bounds, vertex_bounds, first, end, scratch),
                                    offset=4 * first)
            release_pages(indices, first, end)
        self.vertex_arrays = shaders.also_drawing(self.index_buffer)
        #: (Q,) int64 the batch of each part.
        self.part_batch = np.repeat(tree.batch, np.diff(tree.cluster_parts))
        self.commands = ctx.buffer(reserve=20 * max(1, tree.part_boxes.shape[0]))
        #: The last frame's cut, for its other tiles, and what it was made for.
        self._cut: tuple[tuple[Camera, tuple[int, int], float] | None, LodCut] = (None, LodCut.full())
        chunks = scene.chunks
        starts = np.minimum(chunks.batch_bounds[:-1], max(chunks.chunk_count - 1, 0))
        boxes = np.zeros((len(scene.batches), 2, 3), np.float32) if not chunks.chunk_count else np.stack(
            [np.minimum.reduceat(chunks.boxes[:, 0], starts), np.maximum.reduceat(chunks.boxes[:, 1], starts)], axis=1)
        opaque = np.array([batch.alpha_mode == "OPAQUE" for batch in scene.batches], bool)
        #: The batches a moving frame may draw without back faces (opaque, closed) and their boxes (B, 2, 3).
        self.solids = (tree.batch_closed & opaque & (np.diff(chunks.batch_bounds) > 0), boxes)

    def back_culled(self, camera: Camera, size: tuple[int, int], bounds: np.ndarray,
                    error_px: float, whole: bool = False) -> np.ndarray | None:
        """(B,) bool the batches a ``size`` frame at ``error_px`` (0: full detail) of a scene within
        ``bounds`` (2, 3) draws without back faces (None: none), nothing clipped away: a moving frame's
        closed solids seen from outside (:func:`node.culling.lod.back_faces_hidden`; llvmpipe spends
        about 0.3 of a frame's CPU on the back half of a closed scan). ``whole``: the scene is a part
        of one within ``bounds`` (a sort-last share, whose batches are marked closed as the whole
        scene's: :func:`node.scene.ingest.whole_batches_closed`), whose batches' boxes it does not
        know: each solid is taken to fill ``bounds``."""
        closed, boxes = self.solids
        if error_px <= 0.0 or not closed.any():
            return None
        if whole:
            boxes = np.broadcast_to(np.asarray(bounds, np.float32), boxes.shape)
        return back_faces_hidden(closed, boxes, camera, size, near_far_from_bounds(camera, bounds)[0])

    def cut(self, camera: Camera, size: tuple[int, int], error_px: float) -> LodCut:
        """The frame's levels (:func:`node.culling.lod.lod_cut`) for ``camera`` in a ``size`` frame
        within ``error_px`` pixels; the last frame's is kept for its other tiles."""
        key = (camera, size, error_px)
        if self._cut[0] != key:
            self._cut = (key, lod_cut(self.tree, camera, size, error_px))
        return self._cut[1]

    def tile_runs(self, cut: LodCut, matrix: np.ndarray, size: tuple[int, int], rect: Rect,
                  clip: np.ndarray | None, skip: np.ndarray) -> DrawRuns:
        """:meth:`runs` of the tile ``rect`` of the (4, 4) full-frame ``matrix`` of a ``size`` frame, less
        the parts wholly cut away by the (P, 4) ``clip`` planes, but those of the batches ``skip`` marks;
        nearest first by ``matrix``'s view depth (the same order in every tile of the frame)."""
        planes = frustum_planes_from_matrix(matrix, size, rect)
        if clip is not None:
            planes = np.vstack((planes, clip))
        return self.runs(cut, planes, skip if skip.any() else None, matrix)

    @property
    def nbytes(self) -> int:
        return int(self.index_buffer.size + self.commands.size)

    def runs(self, cut: LodCut, planes: np.ndarray | None, skip: np.ndarray | None,
             view_proj: np.ndarray | None = None) -> DrawRuns:
        """The cut's clusters touching the tile of ``planes`` (None: all of them), but those of the
        batches ``skip`` (B,) marks, as index runs of this buffer (batch by batch; within a batch nearest
        first by the clip w of their boxes' centres under the (4, 4) ``view_proj``, ties by cluster;
        None: in cluster order), of each cluster its parts touching the tile, consecutive ones in one
        run; written to :attr:`commands`."""
        tree, nodes = self.tree, cut.nodes
        if skip is not None and nodes.size:
            nodes = nodes[~skip[tree.batch[nodes]]]
        if planes is not None and nodes.size:
            nodes = nodes[boxes_in_frustum(tree.boxes[nodes], planes)]
        if view_proj is not None and nodes.size:
            w_row = np.asarray(view_proj, np.float64)[3]
            depth = (tree.boxes[nodes].astype(np.float64).sum(axis=1) * 0.5) @ w_row[:3]
            nodes = nodes[np.lexsort((nodes, depth, tree.batch[nodes]))]
        counts = tree.cluster_parts[nodes + 1] - tree.cluster_parts[nodes]
        parts = np.repeat(tree.cluster_parts[nodes] - np.cumsum(counts) + counts, counts) + np.arange(int(counts.sum()))
        if planes is not None and parts.size:
            parts = parts[boxes_in_frustum(tree.part_boxes[parts], planes)]
        # A run starts at a part that does not follow the one before it in the buffer (the first of a
        # cluster drawn after another, or after a part left out) or in its batch.
        batch = self.part_batch[parts]
        heads = np.flatnonzero((np.diff(parts, prepend=-2) != 1) | (np.diff(batch, prepend=-1) != 0))
        first = tree.part_bounds[parts[heads]]
        end = tree.part_bounds[np.append(parts[heads[1:] - 1], parts[-1:]) + 1]
        runs = DrawRuns(batch[heads], first, end - first, 0)
        if parts.size:
            self.commands.write(indirect_commands(np.stack([runs.first, runs.count], axis=1)).tobytes())
        return runs

    def release(self) -> None:
        """Free the buffers (the vertex arrays go with the programs that made them)."""
        self.index_buffer.release()
        self.commands.release()
