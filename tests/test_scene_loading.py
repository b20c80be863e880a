"""Scene loading without GL: every shared scene, glTF transforms and instancing, materials,
broken files, and the generated built-in scenes."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import trimesh

from node.scene.builtin import BUILTIN_SCENES, CLUSTER_CENTER, build_builtin_scene
from node.scene.chunks import MAX_GROUPS
from node.scene.data import SceneData
from node.scene.loading import load_scene, smooth_vertex_normals
from node.scene.mesh import MeshBatch, SceneError
from tests.conftest import scene_path

#: A face limit no mesh reaches: batches stay unsplit, in file order.
UNSPLIT = 1 << 40

#: The test scenes: file, triangles (instances counted), drawn mesh instances.
SHARED_SCENES = [
    ("bunny/bun_zipper.ply", 69_451, 1),
    ("large_scan/stanford_dragon_vrip_res2_202k.ply", 202_520, 1),
    ("large_scan/stanford_lucy_240k.ply", 239_768, 1),
    ("large_scan/threedscans_pan_990k.ply", 990_772, 1),
    ("multi_object/sd_macross_city_diorama.glb", 102_822, 24),
    ("gltf_small/2CylinderEngine.glb", 121_496, 115),
    ("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf", 3_624, 5),
    ("gltf_small/Duck.glb", 4_212, 1),
]


@functools.cache
def shared_scene(relative: str) -> SceneData:
    return load_scene(str(scene_path(relative)))


def check_layout(scene: SceneData) -> None:
    """The SceneData contract: dtypes, shapes, unit normals, consistent bounds, chunks and groups."""
    assert np.isfinite(scene.bounds).all() and (scene.bounds[0] < scene.bounds[1]).all()
    groups = len(scene.groups.counts)
    assert scene.groups.boxes.shape == (groups, 6)
    owners = np.array([b.owner for b in scene.batches])[scene.chunks.batch]
    changes = int(np.count_nonzero(np.diff(owners)))   # groups never span two objects: one more per change
    merged = scene.chunks.chunk_count > MAX_GROUPS and groups <= MAX_GROUPS + changes
    assert groups == scene.chunks.chunk_count or merged
    assert scene.chunks.index_bounds[-1] == 3 * scene.triangle_count
    assert scene.groups.counts.sum() == scene.triangle_count == sum(b.triangle_count for b in scene.batches)
    assert np.allclose(scene.groups.boxes[:, :3].min(axis=0), scene.bounds[0])
    assert np.allclose(scene.groups.boxes[:, 3:].max(axis=0), scene.bounds[1])
    for batch in scene.batches:
        n = batch.vertex_count
        assert batch.positions.dtype == np.float32 and batch.positions.shape == (n, 3)
        assert batch.normals.dtype == np.float32 and batch.normals.shape == (n, 3)
        assert batch.faces.dtype == np.uint32 and batch.faces.max() < n
        assert batch.base_color.shape == (4,) and batch.base_color.dtype == np.float32
        lengths = np.linalg.norm(batch.normals[batch.faces[:, 0]], axis=1)
        assert np.mean(np.abs(lengths - 1.0) < 1e-3) > 0.99, f"{batch.name}: normals are not unit length"
        if batch.uvs is not None:
            assert batch.uvs.shape == (n, 2) and batch.texture is not None
            assert batch.texture.dtype == np.uint8 and batch.texture.shape[2] == 4
        if batch.colors is not None:
            assert batch.colors.shape == (n, 4) and batch.colors.min() >= 0.0 and batch.colors.max() <= 1.0


@pytest.mark.parametrize(("relative", "triangles", "batches"), SHARED_SCENES, ids=[s[0] for s in SHARED_SCENES])
def test_shared_scene_loads(relative, triangles, batches):
    scene = shared_scene(relative)
    assert scene.triangle_count == triangles
    assert len(scene.batches) == batches
    check_layout(scene)


def test_textured_gltf_keeps_texture_and_factor():
    truck = shared_scene("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf")
    textured = [b for b in truck.batches if b.texture is not None]
    assert len(textured) == 3 and all(b.uvs is not None for b in textured)
    assert len({id(b.texture) for b in textured}) == 1, "one shared image must be decoded once"
    assert textured[0].texture.shape == (2048, 2048, 4)
    plain = [b for b in truck.batches if b.texture is None]
    assert any(b.base_color[:3].max() < 0.1 for b in plain), "the truck's dark glass factor is lost"


def test_engine_instances_are_placed_by_node_transforms():
    engine = shared_scene("gltf_small/2CylinderEngine.glb")
    by_mesh: dict[str, list[MeshBatch]] = {}
    for batch in engine.batches:
        by_mesh.setdefault(batch.name.split("/", 1)[1], []).append(batch)
    assert len(by_mesh) == 34
    instances = max(by_mesh.values(), key=len)
    assert len(instances) > 1
    centres = {tuple(np.round(b.positions.mean(axis=0), 3)) for b in instances}
    assert len(centres) == len(instances), "instances of one mesh must sit at different places"


def export_rotated_glb(tmp_path, transform: np.ndarray) -> tuple:
    """A GLB whose only node carries ``transform``; returns (path, local mesh)."""
    mesh = trimesh.creation.icosphere(subdivisions=2)
    mesh.vertices *= [1.0, 2.0, 0.5]
    normals = np.asarray(mesh.vertex_normals).copy()
    scene = trimesh.Scene()
    scene.add_geometry(mesh, node_name="ellipsoid", geom_name="ellipsoid", transform=transform)
    path = tmp_path / "ellipsoid.glb"
    path.write_bytes(scene.export(file_type="glb"))
    return path, np.asarray(mesh.vertices), normals


def test_gltf_node_transform_is_baked_into_positions_and_normals(tmp_path):
    rotation = trimesh.transformations.rotation_matrix(0.7, [1.0, 2.0, 0.5])
    transform = trimesh.transformations.translation_matrix([3.0, -1.0, 2.0]) @ rotation @ np.diag([2.0, 1.0, 3.0, 1.0])
    path, local_vertices, local_normals = export_rotated_glb(tmp_path, transform)
    (batch,) = load_scene(str(path), face_limit=UNSPLIT).batches   # splitting would re-order the vertices
    expected = local_vertices @ transform[:3, :3].T + transform[:3, 3]
    assert np.allclose(batch.positions, expected, atol=1e-4)
    world_normals = local_normals @ np.linalg.inv(transform[:3, :3])
    world_normals /= np.linalg.norm(world_normals, axis=1, keepdims=True)
    assert np.allclose(batch.normals, world_normals, atol=1e-4), "normals need the inverse-transpose"
    outward = np.einsum("ij,ij->i", batch.normals, batch.positions - transform[:3, 3])
    assert (outward > 0).all()


def test_scan_without_normals_gets_smooth_outward_normals():
    bunny = shared_scene("bunny/bun_zipper.ply")
    (batch,) = bunny.batches
    centre = batch.positions.mean(axis=0)
    outward = np.einsum("ij,ij->i", batch.normals, batch.positions - centre)
    assert np.mean(outward > 0) > 0.8


def test_smooth_vertex_normals_of_a_flat_square():
    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    assert np.allclose(smooth_vertex_normals(positions, faces), [[0, 0, 1]] * 4)


def test_obj_stl_and_vertex_coloured_ply_load(tmp_path):
    obj = tmp_path / "quad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nf 1 3 4\n")
    assert load_scene(str(obj)).triangle_count == 2
    stl = tmp_path / "box.stl"
    stl.write_bytes(trimesh.creation.box().export(file_type="stl"))
    assert load_scene(str(stl)).triangle_count == 12
    ply = tmp_path / "coloured.ply"
    coloured = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]],
                               vertex_colors=[[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255]])
    ply.write_bytes(coloured.export(file_type="ply"))
    (batch,) = load_scene(str(ply)).batches
    assert np.allclose(batch.colors, [[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 1, 1]])


def broken_files(tmp_path):
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(np.random.default_rng(1).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    truncated = tmp_path / "truncated.glb"
    truncated.write_bytes(scene_path("gltf_small/Duck.glb").read_bytes()[:5000])
    unknown = tmp_path / "model.xyz"
    unknown.write_text("1 2 3\n")
    empty = tmp_path / "empty.obj"
    empty.write_text("v 0 0 0\nv 1 0 0\n")
    gltf_without_bin = tmp_path / "CesiumMilkTruck.gltf"
    gltf_without_bin.write_bytes(scene_path("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf").read_bytes())
    return {"garbage bytes": (garbage, "corrupt"), "truncated glb": (truncated, "corrupt"),
            "gltf without its .bin": (gltf_without_bin, "CesiumMilkTruck0.bin"),
            "unknown extension": (unknown, "unsupported file type"),
            "missing file": (tmp_path / "absent.glb", "no such file"), "no triangles": (empty, "no triangles")}


@pytest.mark.parametrize("case", ["garbage bytes", "truncated glb", "gltf without its .bin", "unknown extension",
                                  "missing file", "no triangles"])
def test_broken_file_raises_one_line_scene_error(tmp_path, case):
    path, reason = broken_files(tmp_path)[case]
    with pytest.raises(SceneError) as caught:
        load_scene(str(path))
    message = str(caught.value)
    assert str(path) in message and reason in message
    assert "\n" not in message


def test_unknown_builtin_scene_names_the_choices():
    with pytest.raises(SceneError, match="cluster"):
        load_scene("builtin:nope")


@pytest.mark.parametrize("name", BUILTIN_SCENES)
def test_builtin_scenes_load_and_are_deterministic(name):
    first, second = load_scene(f"builtin:{name}"), build_builtin_scene(name)
    check_layout(first)
    assert len(first.batches) == len(second.batches)
    for a, b in zip(first.batches, second.batches, strict=True):
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.base_color, b.base_color)


def test_cluster_scene_is_dense_on_one_side():
    scene = load_scene("builtin:cluster")
    assert 150_000 <= scene.triangle_count <= 600_000
    centres_x = (scene.groups.boxes[:, 0] + scene.groups.boxes[:, 3]) / 2.0
    counts = scene.groups.counts
    assert CLUSTER_CENTER[0] < 0.0
    dense, sparse = counts[centres_x < 0.0].sum(), counts[centres_x >= 0.0].sum()
    assert dense > 10 * sparse, "the cluster half of the ground must hold most triangles"
    assert len(scene.batches) > 30, "the balancer's DPBP estimate needs many primitive groups"
