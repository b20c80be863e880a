"""A node's share of the scene in the sort-last mode (issue 10: database decomposition): the
scene's chunks are split into spatially coherent shares sized by the nodes' calibrated speeds
(:func:`tessera.decomposition.data_partition.split_chunks`, seed 003's weights), and a node keeps only its own.
No GL here.

Every node loads the whole file, splits it into the same octree chunks (the same file and the same
``--face-limit`` give the same chunks on every node) and computes the same partition, so no chunk
lists travel: a share is named by its index and the weights. The node then keeps only its share's
faces and the vertices they use, and the whole scene is dropped before anything is uploaded: a
node never keeps geometry it does not own longer than loading needs.

What stays the whole scene's: ``bounds`` (near and far come from them: every node must project
depth alike, or depths from different nodes could not be compared) and the objects with their
measured bounds and triangles (the scene state's bounds, issue 11, likewise).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from node.scene.data import SceneData
from node.scene.mesh import MeshBatch, SceneError
from tessera.decomposition.data_partition import split_chunks


def keep_share(scene: SceneData, weights: Sequence[float], index: int) -> SceneData:
    """Share ``index`` of ``scene`` split over ``weights`` (one per share): its chunks' faces and
    the vertices they use, re-split into chunks of the scene's face limit, with the whole scene's
    bounds and objects. Raises SceneError when the share holds nothing (fewer chunks than shares)."""
    chunks = scene.chunks
    keep = split_chunks(chunks.boxes, chunks.face_counts, weights) == index
    batches = []
    for number, batch in enumerate(scene.batches):
        first, end = int(chunks.batch_bounds[number]), int(chunks.batch_bounds[number + 1])
        if not keep[first:end].any():
            continue
        faces = np.repeat(keep[first:end], chunks.face_counts[first:end])
        batches.append(_with_used_vertices(dataclasses.replace(batch, faces=batch.faces[faces])))
    if not batches:
        raise SceneError(f"{scene.name}: share {index} of {len(weights)} holds no chunk")
    share = SceneData.from_batches(scene.name, batches, chunks.face_limit, scene.objects.objects, scene.animations)
    return dataclasses.replace(share, bounds=scene.bounds, objects=scene.objects)


def _with_used_vertices(batch: MeshBatch) -> MeshBatch:
    """``batch`` with only the vertices its faces use, renumbered in their old order."""
    used = np.unique(batch.faces.reshape(-1))
    renumber = np.zeros(batch.vertex_count, np.uint32)
    renumber[used] = np.arange(used.size, dtype=np.uint32)
    return batch.with_vertices(used, renumber[batch.faces])
