"""Chunks drawn nearest first (:mod:`node.culling.order`): the runs a tile draws, and on llvmpipe
that hidden fragments are no longer drawn while the picture stays the same."""

from __future__ import annotations

import numpy as np
import pytest

from node.culling.order import ChunkGroups, front_to_back
from node.culling.switch import CullMode
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.chunks import SceneChunks
from node.scene.loading import load_scene
from tessera.geometry import default_camera
from tests.conftest import scene_path


def test_groups_of_visible_chunks_come_nearest_first_within_each_batch() -> None:
    """25 chunks in a row along x, 2 faces each: batch 0 is chunks 0-19, batch 1 chunks 20-24; depth
    (clip w) falls with x, so the groups of larger x come first; a group's chunks stay in id order."""
    boxes = np.stack([np.stack([[x, 0, 0], [x + 1, 1, 1]]) for x in range(25)]).astype(np.float32)
    chunks = SceneChunks(batch=np.repeat([0, 1], [20, 5]), index_bounds=np.arange(26) * 6,
                         batch_bounds=np.array([0, 20, 25]), boxes=boxes, face_limit=2)
    groups = ChunkGroups.of(chunks, size=8)
    assert groups.group.tolist() == [0] * 8 + [1] * 8 + [2] * 4 + [3] * 5
    view_proj = np.zeros((4, 4))
    view_proj[3] = (-1.0, 0.0, 0.0, 30.0)
    runs = front_to_back(chunks, groups, np.array([2, 13]), np.array([11, 22]), view_proj)
    drawn = [(int(b), int(f) // 6, int(f + c) // 6) for b, f, c in zip(runs.batch, runs.first, runs.count, strict=True)]
    assert drawn == [(0, 16, 20), (0, 8, 11), (0, 13, 16), (0, 2, 8), (1, 20, 22)]
    assert runs.chunks == 18 and runs.batch_slices() == [(0, 0, 4), (1, 4, 1)]
    view_proj[3] = (1.0, 0.0, 0.0, 0.0)
    runs = front_to_back(chunks, groups, np.array([0]), np.array([25]), view_proj)
    assert runs.first.tolist() == [0, 120] and runs.count.tolist() == [120, 30], "in id order, a run a batch"


@pytest.mark.gl
def test_nearest_first_shades_the_bunny_once_a_pixel_and_draws_the_same_picture(ctx) -> None:
    """The bunny from its default camera: chunk order (culling off draws it) reaches two surfaces a
    pixel back to front; nearest first, about one passes the depth test, and not a pixel changes."""
    scene = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    size = (320, 180)
    camera = default_camera(scene.bounds, aspect=size[0] / size[1])
    passed, pictures = [], []
    for culling in (CullMode.OFF, CullMode.CPU):
        renderer = TileRenderer(ctx, scene, culling=culling, shading=ShadingOptions(msaa=1))   # a sample a pixel
        try:
            renderer.render_frame(camera, size)
            query = ctx.query(samples=True)
            with query:
                pictures.append(renderer.render_frame(camera, size).pixels)
            passed.append(query.samples)
        finally:
            renderer.release()
    covered = int(np.any(pictures[0] != pictures[0][0, 0], axis=2).sum())
    assert np.array_equal(pictures[0], pictures[1])
    assert passed[0] > 1.8 * covered and passed[1] < 1.25 * covered, (covered, passed)
