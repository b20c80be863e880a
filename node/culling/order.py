"""Front-to-back draw order of a tile's visible chunks (issue 20: the cost of physically based shading).

Opaque batches are drawn by a fragment shader without discards (:func:`node.gl.shading.fragment_shader`),
so the depth test runs before the shader and a fragment behind what is already drawn is never shaded.
That saves only what is drawn behind something nearer: chunks come in octree (Morton) order, which
for a camera on the side of the scene's larger coordinates is back to front, every fragment shaded
(on the default camera of the scans 2.0-3.2 shaded fragments per covered pixel; front to back 1.0).

So a batch's visible chunks are drawn in groups of :data:`GROUP_CHUNKS` consecutive chunks (an
octree neighbourhood), nearest group first by the view depth (clip w) of the group's centre; within a
group, and between batches, the order stays as it was. Every tile of a frame sorts by the same
full-frame matrix, so the chunks a pixel sees come in the same order in every tile. Under the depth
test the order changes no pixel but exactly coplanar overlaps inside one batch (the first drawn wins);
blended batches are one chunk each (:mod:`node.scene.chunks`), so their faces keep their order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from node.scene.chunks import DrawRuns, SceneChunks

#: Chunks per group sorted as one: aligned runs of chunk ids (octree neighbours, about 1.5 k faces
#: at the default face limit); fewer, longer draw commands than sorting single chunks.
GROUP_CHUNKS = 8


@dataclass(frozen=True, eq=False)
class ChunkGroups:
    """The groups of a scene's chunks: chunk i is in group ``group[i]`` (C,) int64, group g is
    chunks [g·size, (g + 1)·size) cut at batch ends (``size`` :data:`GROUP_CHUNKS`); ``centers``
    (G, 3) float64 the groups' box centres (midpoints of their chunks' boxes)."""

    group: np.ndarray
    centers: np.ndarray

    @classmethod
    def of(cls, chunks: SceneChunks, size: int = GROUP_CHUNKS) -> ChunkGroups:
        ids = np.arange(chunks.chunk_count)
        first_of_batch = chunks.batch_bounds[chunks.batch]
        # Groups restart at each batch, so no group spans two batches.
        key = chunks.batch * (chunks.chunk_count + size) + (ids - first_of_batch) // size
        starts = np.flatnonzero(np.diff(key, prepend=-1) != 0)
        group = np.cumsum(np.diff(key, prepend=-1) != 0) - 1
        lo = np.minimum.reduceat(chunks.boxes[:, 0].astype(np.float64), starts, axis=0)
        hi = np.maximum.reduceat(chunks.boxes[:, 1].astype(np.float64), starts, axis=0)
        return cls(group.astype(np.int64), (lo + hi) * 0.5)


def front_to_back(chunks: SceneChunks, groups: ChunkGroups, first: np.ndarray, end: np.ndarray,
                  view_proj: np.ndarray) -> DrawRuns:
    """Draw runs of the visible chunk ranges [first[i], end[i]) (R,) sorted, disjoint: per batch in
    batch order, the groups nearest first by clip w under ``view_proj`` (4, 4) world→clip (ties by
    group), each group's visible chunks in id order, consecutive chunks of one run merged."""
    first = np.asarray(first, dtype=np.int64)
    end = np.asarray(end, dtype=np.int64)
    if first.size == 0:
        return chunks.runs(first, end)
    lengths = end - first
    ids = np.repeat(first - np.cumsum(lengths) + lengths, lengths) + np.arange(int(lengths.sum()))
    group = groups.group[ids]
    w_row = np.asarray(view_proj, dtype=np.float64)[3]
    depth = groups.centers @ w_row[:3] + w_row[3]
    ids = ids[np.lexsort((ids, group, depth[group], chunks.batch[ids]))]
    heads = np.flatnonzero(np.diff(ids, prepend=-2) != 1)
    ends = np.append(ids[heads[1:] - 1], ids[-1]) + 1
    return chunks.runs(ids[heads], ends)
