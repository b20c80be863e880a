"""A loaded scene's objects (issue 11, no GL): glTF nodes matched to trimesh's graph, one object per
PLY file or built-in batch, each batch's owner, the file's animations, and the scene at a time."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from node.scene.builtin import TRAFFIC_HALF, TRAFFIC_LOOP_S
from node.scene.loading import load_scene
from node.scene.objects import geometry_owners, gltf_objects, read_gltf
from tessera.scene.graph import ObjectGraph
from tessera.scene.state import ObjectPatch, UnknownObjectError
from tests.conftest import scene_path

TRUCK = "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"
ENGINE = "gltf_small/2CylinderEngine.glb"


def test_milk_truck_objects_and_animation() -> None:
    scene = load_scene(str(scene_path(TRUCK)))
    objects = scene.objects
    # Unnamed glTF nodes take their index as name, as in trimesh's graph: 0 the body, 1 and 3 the
    # axles (matrices), 2 and 4 the wheels (rotations, animated).
    assert sorted(objects.names) == ["0", "1", "2", "3", "4"]
    assert {name: objects.objects[objects.objects[objects.lookup(name)].parent].name for name in ("2", "4")} \
        == {"2": "1", "4": "3"}
    assert objects.objects[objects.lookup("1")].base.translation == pytest.approx((-1.35233, 0.427722, 0.0), abs=1e-6)
    assert sum(item.triangles for item in objects.objects) == scene.triangle_count
    wheel_batches = {objects.names[b.owner] for b in scene.batches if b.name.endswith("Wheels")}
    assert wheel_batches == {"2", "4"}
    (animation,) = scene.animations
    assert {c.target for c in animation.channels} == {"2", "4"}
    state = scene.state_at(0.5)
    assert state.time == 0.5
    assert state.objects["2"].rotation == pytest.approx(tuple(animation.sample(0.5)["2"].rotation or ()))
    assert state.objects["0"] == objects.objects[objects.lookup("0")].base
    posed = scene.state_at(0.5, {"2": ObjectPatch(visible=False)})
    assert not posed.objects["2"].visible and posed.objects["2"].rotation == state.objects["2"].rotation
    with pytest.raises(UnknownObjectError, match="unknown object 'wheel'"):
        scene.state_at(0.0, {"wheel": ObjectPatch()})


@pytest.mark.parametrize("relative", [TRUCK, ENGINE, "gltf_small/Duck.glb"])
def test_base_pose_matches_trimesh_graph(relative: str) -> None:
    path = scene_path(relative)
    loaded = trimesh.load(str(path), force="scene", process=False)
    objects, _ = gltf_objects(read_gltf(path).json)
    graph = ObjectGraph(objects)
    world = graph.world_matrices(graph.base)
    for node, owner in geometry_owners(loaded.graph, objects).items():
        scale = np.abs(world[owner]).max()
        np.testing.assert_allclose(world[owner], loaded.graph[node][0], rtol=1e-7, atol=1e-7 * scale)


def test_engine_keeps_its_hierarchy_and_face_limit_keeps_the_objects() -> None:
    scene = load_scene(str(scene_path(ENGINE)))
    assert len(scene.objects) == 82 and scene.animations == ()
    assert sum(item.triangles for item in scene.objects.objects) == scene.triangle_count
    resplit = scene.with_face_limit(64)
    assert resplit.objects.names == scene.objects.names
    assert [item.triangles for item in resplit.objects.objects] == [item.triangles for item in scene.objects.objects]


def test_a_ply_file_is_one_object_and_a_builtin_batch_is_one() -> None:
    bunny = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    (only,) = bunny.objects.objects
    assert (only.name, only.parent, only.triangles) == ("bun_zipper", -1, bunny.triangle_count)
    np.testing.assert_array_equal(only.bounds, bunny.bounds)
    spheres = load_scene("builtin:spheres")
    assert spheres.objects.names == ("ground", "sphere0", "sphere1", "sphere2", "sphere3")
    assert [spheres.objects.names[b.owner] for b in spheres.batches] == list(spheres.objects.names)


def test_traffic_moves_deterministically_and_loops() -> None:
    scene = load_scene("builtin:traffic")
    again = load_scene("builtin:traffic")
    assert scene.objects.names[0] == "road" and "sign" in scene.objects.names and len(scene.objects) == 13
    assert not scene.objects.moved(scene.state_at(0.0)).any()        # t = 0 is the base pose
    for time in (0.0, 1.7, 33.3):
        assert scene.state_at(time).same_as(again.state_at(time))
    assert dict(scene.state_at(TRAFFIC_LOOP_S).objects) == dict(scene.state_at(0.0).objects)   # it loops
    # Lane 0 drives +x at 16 units / 8 s; lane 1 −x at 16 / 16 s (no wrap in these 0.5 s).
    first, later = scene.state_at(0.0).objects, scene.state_at(0.5).objects
    assert later["car0_0"].translation[0] - first["car0_0"].translation[0] == pytest.approx(1.0)
    assert later["car1_0"].translation[0] - first["car1_0"].translation[0] == pytest.approx(-0.5)
    xs = [scene.state_at(t).objects["car3_1"].translation[0] for t in np.linspace(0.0, 40.0, 401)]
    assert min(xs) >= -TRAFFIC_HALF and max(xs) <= TRAFFIC_HALF and max(xs) - min(xs) > 15.0
    # The sign turns about y, 45° a second.
    np.testing.assert_allclose(scene.state_at(1.0).objects["sign"].rotation,
                               [0.0, np.sin(np.pi / 8), 0.0, np.cos(np.pi / 8)], atol=1e-12)
