"""Culling moved batches in their own frame (:mod:`node.culling.objects`): the tile's planes carried
by the model matrix keep exactly the chunks whose moved boxes a world-space cull keeps. No GL."""

from __future__ import annotations

import numpy as np

from node.culling.bvh import build_chunk_bvh, cull
from node.culling.objects import MovedCuller
from node.scene.chunks import SceneChunks
from tessera.scene.graph import transform_boxes


def _chunks() -> SceneChunks:
    """Two batches: batch 0 is 4 unit cubes along x (x = 0…4), batch 1 one cube at x = 10."""
    boxes = np.array([[[x, 0, 0], [x + 1, 1, 1]] for x in (0, 1, 2, 3, 10)], dtype=np.float32)
    return SceneChunks(batch=np.array([0, 0, 0, 0, 1]), index_bounds=np.arange(6) * 30,
                       batch_bounds=np.array([0, 4, 5]), boxes=boxes, face_limit=10)


def _slab(x0: float, x1: float) -> np.ndarray:
    """(6, 4) planes keeping x0 ≤ x ≤ x1 (the other four planes keep everything)."""
    return np.array([[1, 0, 0, -x0], [-1, 0, 0, x1], [0, 1, 0, 1e3], [0, -1, 0, 1e3], [0, 0, 1, 1e3],
                     [0, 0, -1, 1e3]], dtype=np.float64)


def _translate(dx: float) -> np.ndarray:
    model = np.identity(4)
    model[0, 3] = dx
    return model


def test_carried_planes_cull_the_moved_chunks():
    chunks = _chunks()
    culler = MovedCuller(chunks)
    # batch 0 moved by +20: its cubes sit at x = 20…24; the slab 21.5…22.5 touches the 2nd and 3rd.
    runs = culler.cull(_slab(21.5, 22.5), [0], _translate(20.0)[None])
    assert (runs.batch.tolist(), runs.first.tolist(), runs.count.tolist(), runs.chunks) == ([0], [30], [60], 2)
    # The same as culling the moved boxes in world space.
    world = cull(build_chunk_bvh(transform_boxes(chunks.boxes[:4], _translate(20.0))), _slab(21.5, 22.5))
    assert world.visible_chunks.tolist() == [1, 2]
    # Where the batch was, nothing is kept; a slab around all of it keeps it whole without its tree.
    assert culler.cull(_slab(0.0, 4.0), [0], _translate(20.0)[None]).chunks == 0
    whole = culler.cull(_slab(19.0, 30.0), [0, 1], np.stack([_translate(20.0), _translate(12.0)]))
    assert (whole.batch.tolist(), whole.first.tolist(), whole.count.tolist()) == ([0, 1], [0, 120], [120, 30])
    assert 1 not in culler._trees and 0 in culler._trees


def test_no_planes_keeps_every_chunk_of_the_moved_batches():
    runs = MovedCuller(_chunks()).cull(None, [1], _translate(5.0)[None])
    assert (runs.batch.tolist(), runs.first.tolist(), runs.count.tolist()) == ([1], [120], [30])
    assert MovedCuller(_chunks()).cull(_slab(0, 1), [], np.zeros((0, 4, 4))).chunks == 0
