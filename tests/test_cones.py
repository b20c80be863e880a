"""Normal cones (issue 32, node/scene/cones.py, node/culling/cones.py): every triangle's normal lies
within its run's stored cone (chunks, coarse clusters, parts of the levels), worked out in blocks as
at once; a run that the cone test finds facing away holds no front-facing triangle from random eyes,
near and inside the model too, and from outside something is found; a moving frame that leaves out
the chunks and coarse parts facing away is the frame drawn without that bit for bit (the GL culls
their triangles anyway), tiles and depth layers too, and draws fewer triangles."""

from __future__ import annotations

import numpy as np
import pytest

from node.culling.cones import facing_away
from node.gl.lod_draws import LodDraws
from node.gl.renderer import TileRenderer
from node.scene import cones as cones_module
from node.scene.cones import NO_CONE, normal_cones
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.lod import LodTree, build_lod
from tessera.geometry import Camera, Rect, default_camera
from tests.conftest import scene_path
from tests.culling_support import random_cameras

DRAGON = "large_scan/stanford_dragon_vrip_res2_202k.ply"


@pytest.fixture(scope="module")
def dragon() -> tuple[SceneData, LodTree]:
    scene = load_scene(str(scene_path(DRAGON)))
    return scene, build_lod(scene, lambda fraction, message: None)


def unit_normals(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """((F, 3) unit normals of ``faces`` (F, 3), (F,) bool which have an area)."""
    corners = np.asarray(positions, np.float64)[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    length = np.linalg.norm(normals, axis=1)
    return normals / np.where(length > 0, length, 1.0)[:, None], length > 0


def runs_of(tree: LodTree, scene: SceneData) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Per kind of run: (cones (K, 4), boxes (K, 2, 3), the faces (F, 3) of all runs, run of each face (F,))."""
    (batch,) = scene.batches
    chunk_faces = np.asarray(batch.faces).reshape(-1, 3)
    coarse = np.asarray(tree.indices).reshape(-1, 3)
    return {
        "chunk": (tree.chunk_cones, scene.chunks.boxes, chunk_faces,
                  np.repeat(np.arange(scene.chunks.chunk_count), scene.chunks.face_counts)),
        "cluster": (tree.cluster_cones, tree.boxes, coarse, np.repeat(np.arange(tree.node_count), tree.triangles)),
        "part": (tree.part_cones, tree.part_boxes, coarse,
                 np.repeat(np.arange(tree.part_boxes.shape[0]), np.diff(tree.part_bounds) // 3)),
    }


def test_every_triangle_lies_within_its_runs_cone(dragon):
    scene, tree = dragon
    positions = scene.batches[0].positions
    assert tree.chunk_cones.shape == (scene.chunks.chunk_count, 4) and tree.chunk_cones.dtype == np.float32
    assert tree.cluster_cones.shape == (tree.node_count, 4)
    assert tree.part_cones.shape == (tree.part_boxes.shape[0], 4)
    for kind, (cones, _, faces, run) in runs_of(tree, scene).items():
        normals, area = unit_normals(positions, faces)
        axis = cones[run, :3].astype(np.float64)
        axis /= np.linalg.norm(axis, axis=1)[:, None]
        dots = np.einsum("ij,ij->i", normals, axis)
        assert np.all(dots[area] >= cones[run[area], 3]), kind
    assert np.mean(tree.chunk_cones[:, 3] > 0) > 0.4, "most chunks of a scan have a cone"
    assert np.mean(tree.part_cones[:, 3] > 0) > 0.1


def test_cones_worked_out_in_blocks_are_the_same(dragon, monkeypatch):
    scene, _ = dragon
    batch = scene.batches[0]
    faces = np.asarray(batch.faces).reshape(-1, 3)
    starts = scene.chunks.index_bounds[:-1] // 3
    whole = normal_cones(batch.positions, faces, starts)
    monkeypatch.setattr(cones_module, "BLOCK_FACES", 1000)
    assert np.array_equal(normal_cones(batch.positions, faces, starts), whole)


def test_a_flat_run_has_a_narrow_cone_and_a_closed_one_none():
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]], np.float32)
    square = np.array([[0, 1, 2], [1, 3, 2]])
    tetrahedron = np.array([[0, 2, 1], [0, 1, 4], [0, 4, 2], [1, 2, 4]])
    degenerate = np.array([[0, 1, 1]])
    cones = normal_cones(positions, np.vstack([square, tetrahedron, degenerate]), np.array([0, 2, 6, 6]))
    assert np.allclose(cones[0, :3], [0, 0, 1]) and cones[0, 3] > 0.9999
    assert cones[1, 3] == NO_CONE, "a closed solid's normals point every way"
    assert cones[2, 3] == NO_CONE and cones[3, 3] == NO_CONE, "no triangles, or none with an area"


def test_no_run_found_facing_away_holds_a_front_facing_triangle(dragon):
    scene, tree = dragon
    positions = np.asarray(scene.batches[0].positions, np.float64)
    lo, hi = scene.chunks.boxes[:, 0].min(axis=0), scene.chunks.boxes[:, 1].max(axis=0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    rng = np.random.default_rng(7)
    directions = rng.normal(size=(12, 3))
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    eyes = np.vstack([centre + directions * radius * rng.uniform(0.2, 4.0, (12, 1)),   # inside and around
                      positions[rng.integers(0, len(positions), 4)] + rng.normal(scale=1e-3 * radius, size=(4, 3))])
    culled = 0
    for kind, (cones, boxes, faces, run) in runs_of(tree, scene).items():
        normals, area = unit_normals(positions, faces)
        for eye in eyes:
            away = facing_away(cones, boxes, eye)
            front = area & (np.einsum("ij,ij->i", normals, positions[faces[:, 0]] - eye) <= 0.0)
            assert not np.any(away[run[front]]), f"{kind}: a run facing away holds a front face from {eye}"
            culled += int(away.sum())
    assert culled > 0.05 * len(eyes) * (scene.chunks.chunk_count + tree.part_boxes.shape[0])


def cameras_of(scene: SceneData, size: tuple[int, int]) -> list[Camera]:
    """The default camera, random ones around and inside the model, one near its surface."""
    lo, hi = scene.bounds
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    surface = np.asarray(scene.batches[0].positions[1000], np.float64)
    near = Camera(eye=tuple((surface + (surface - centre) * 0.05).tolist()), target=tuple(centre.tolist()))
    inside = Camera(eye=tuple(centre.tolist()), target=tuple((centre - np.array([0.0, 0.0, radius])).tolist()))
    return [default_camera(scene.bounds, aspect=size[0] / size[1]), *random_cameras(scene.bounds, 4, seed=3),
            near, inside]


@pytest.mark.gl
def test_the_frame_without_what_faces_away_is_the_same_bit_for_bit(ctx, dragon, monkeypatch):
    scene, tree = dragon
    renderer = TileRenderer(ctx, scene)
    renderer.attach_lod(tree)
    size, error_px = (480, 270), 0.5
    tile = Rect(100, 40, 140, 100)
    fewer = 0
    facing = LodDraws.facing
    for camera in cameras_of(scene, size):
        drawn = []
        for leave_out in (True, False):
            monkeypatch.setattr(LodDraws, "facing", facing if leave_out else lambda self, camera, backless: None)
            frame = renderer.render_frame(camera, size, lod_error_px=error_px)
            part = renderer.render_tile(camera, size, tile, lod_error_px=error_px)
            layer = renderer.render_layer(camera, size, tile, lod_error_px=error_px)
            drawn.append((frame, part, layer))
        (frame, part, layer), (full_frame, full_part, full_layer) = drawn
        assert np.array_equal(frame.pixels, full_frame.pixels), camera
        assert np.array_equal(part.pixels, full_part.pixels), camera
        assert np.array_equal(layer.pixels, full_layer.pixels) and np.array_equal(layer.depth, full_layer.depth)
        assert frame.triangles <= full_frame.triangles
        fewer += frame.triangles < 0.98 * full_frame.triangles
    assert fewer >= 4, "from outside, 2 % of the triangles or more are left out (3-5 % here)"
    renderer.release()
