"""The coordinator's scene timeline (issue 11): the animation clock (play, pause, jump, speed,
looping), user poses merged and winning over the animation, states bound into the log as versions,
bad values refused with nothing changed; objects and animations travel from node to coordinator
bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from node.scene.loading import load_scene
from tessera.scene.animation import Animation, AnimationError, Channel, Sampler
from tessera.scene.graph import ObjectGraph, SceneObject
from tessera.scene.state import ObjectPatch, SceneStateError, UnknownObjectError
from tessera.scene.timeline import SceneTimeline, merged
from tests.conftest import scene_path

BOX = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def timeline(now: float = 0.0) -> SceneTimeline:
    """``car`` drives from x = 0 to x = 10 over [0, 2] s; ``tree`` stands still."""
    graph = ObjectGraph([SceneObject("car", bounds=BOX, triangles=12), SceneObject("tree", bounds=BOX + 5.0)])
    drive = Sampler(np.array([0.0, 2.0]), np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0]]), "LINEAR")
    return SceneTimeline(graph, [Animation("drive", (Channel("car", "translation", drive),))], now)


def car_x(scene: SceneTimeline, now: float) -> float:
    return scene.state_at(now).objects["car"].translation[0]


def test_starts_paused_at_the_start_as_version_zero():
    scene = timeline(now=5.0)
    assert not scene.playing and not scene.animating and scene.time_at(100.0) == 0.0
    assert scene.log.current.version == 0 and scene.bind(100.0) is scene.log.current
    assert (scene.start, scene.end) == (0.0, 2.0)


def test_playing_runs_at_speed_and_loops_over_the_animation():
    scene = timeline()
    scene.set_animation(10.0, playing=True)
    assert scene.animating
    assert scene.time_at(10.5) == 0.5 and car_x(scene, 10.5) == 2.5
    assert scene.time_at(13.0) == pytest.approx(1.0), "3 s into a 2 s loop"
    scene.set_animation(13.0, speed=-0.5)
    assert scene.time_at(13.0) == pytest.approx(1.0), "changing speed keeps the time"
    assert scene.time_at(17.0) == pytest.approx(1.0), "backwards, 2 s later, one loop back"
    scene.set_animation(17.0, playing=False)
    assert scene.time_at(99.0) == pytest.approx(1.0) and not scene.animating


def test_jump_while_paused_is_exact_and_not_looped():
    scene = timeline()
    scene.set_animation(3.0, time=0.3)
    assert scene.time_at(50.0) == 0.3 and car_x(scene, 50.0) == pytest.approx(1.5)
    scene.set_animation(3.0, time=7.0)
    assert scene.time_at(4.0) == 7.0 and car_x(scene, 4.0) == 10.0, "sampling clamps past the end"


@pytest.mark.parametrize("kwargs, message", [
    ({"time": math.nan}, "time must be a finite number"),
    ({"time": "1"}, "time must be a finite number"),
    ({"speed": math.inf}, "speed must be a finite number"),
    ({"speed": 5000.0}, "speed must be within"),
    ({"playing": 1}, "playing must be true or false"),
])
def test_bad_animation_values_change_nothing(kwargs, message):
    scene = timeline()
    scene.set_animation(0.0, playing=True, speed=2.0)
    with pytest.raises(SceneStateError, match=message):
        scene.set_animation(1.0, **kwargs)
    assert scene.playing and scene.speed == 2.0 and scene.time_at(1.5) == pytest.approx(1.0)


def test_poses_merge_and_win_over_the_animation():
    scene = timeline()
    scene.set_objects({"car": ObjectPatch(scale=(2.0, 2.0, 2.0))})
    scene.set_objects({"car": ObjectPatch(translation=(0.0, 3.0, 0.0)), "tree": ObjectPatch(visible=False)})
    state = scene.state_at(0.0)
    assert state.objects["car"].translation == (0.0, 3.0, 0.0) and state.objects["car"].scale == (2.0, 2.0, 2.0)
    assert not state.objects["tree"].visible
    assert merged(None, ObjectPatch(visible=True)) == ObjectPatch(visible=True)


def test_an_unknown_object_changes_nothing():
    scene = timeline()
    with pytest.raises(UnknownObjectError, match="'bus'"):
        scene.set_objects({"car": ObjectPatch(visible=False), "bus": ObjectPatch(visible=False)})
    assert scene.overrides == {}


def test_bind_makes_a_version_only_when_the_state_changed():
    scene = timeline()
    first = scene.bind(0.0)
    scene.set_animation(0.0, time=1.0)
    second = scene.bind(0.0)
    assert second.version == first.version + 1 and second.time == 1.0
    assert scene.bind(9.0) is second, "paused: the same state"
    assert second.delta_from(first).objects.keys() == {"car"}


def test_objects_json_shows_where_objects_are_now():
    scene = timeline()
    scene.set_animation(0.0, time=2.0)
    car, tree = scene.objects_json(0.0)
    assert car["translation"] == [10.0, 0.0, 0.0] and car["bounds"] == [[9.0, -1.0, -1.0], [11.0, 1.0, 1.0]]
    assert car["triangles"] == 12 and tree["bounds"] == (BOX + 5.0).tolist()
    assert scene.animation_json(0.0) == {"playing": False, "time": 2.0, "speed": 1.0, "start": 0.0, "end": 2.0,
                                         "animations": [{"name": "drive", "start": 0.0, "end": 2.0,
                                                         "targets": ["car"]}]}


def test_an_animation_of_an_unknown_object_is_refused():
    graph = ObjectGraph([SceneObject("car")])
    drive = Sampler(np.array([0.0]), np.array([[0.0, 0.0, 0.0]]), "STEP")
    with pytest.raises(UnknownObjectError):
        SceneTimeline(graph, [Animation("drive", (Channel("bus", "translation", drive),))])


@pytest.mark.parametrize("scene_name", ["builtin:traffic", "truck"])
def test_objects_and_animations_cross_json_bit_for_bit(scene_name):
    spec = str(scene_path("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf")) if scene_name == "truck" else scene_name
    scene = load_scene(spec)
    graph = ObjectGraph.from_json(scene.objects.to_json())
    animations = [Animation.from_keyframes_json(a.keyframes_json()) for a in scene.animations]
    remote = SceneTimeline(graph, animations)
    for time in (0.0, 0.37, 0.9, 41.3):
        remote.set_animation(0.0, time=time)
        assert remote.state_at(0.0).same_as(scene.state_at(time)), f"t = {time}"
    assert graph.names == scene.objects.names
    for mine, theirs in zip(graph.objects, scene.objects.objects, strict=True):
        assert mine.base == theirs.base and mine.parent == theirs.parent and mine.triangles == theirs.triangles
        assert (mine.bounds is None and theirs.bounds is None) or np.array_equal(mine.bounds, theirs.bounds)


@pytest.mark.parametrize("channel, message", [
    ({"path": "weights"}, "path 'weights'"),
    ({"interpolation": "SMOOTH"}, "interpolation 'SMOOTH'"),
    ({"times": [1.0, 0.0]}, "finite and increasing"),
    ({"times": []}, "finite and increasing"),
    ({"values": [[0.0, 0.0, 0.0]]}, "output must be 2 values of 3"),
    ({"values": [[0.0, 0.0], [1.0, 1.0]]}, "output must be 2 values of 3"),
    ({"values": "abc"}, "must be numbers"),
    ({"path": "rotation", "values": [[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]}, "zero quaternion"),
])
def test_bad_keyframes_from_a_node_are_refused(channel, message):
    data = {"name": "a", "channels": [{"target": "car", "path": "translation", "interpolation": "LINEAR",
                                       "times": [0.0, 1.0], "values": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
                                       **channel}]}
    with pytest.raises(AnimationError, match=message):
        Animation.from_keyframes_json(data)
    with pytest.raises(AnimationError, match="no channel"):
        Animation.from_keyframes_json({"name": "empty", "channels": []})


@pytest.mark.parametrize("objects, message", [
    ([{"name": "a", "parent": "b"}, {"name": "b"}], "parent 'b' does not come before it"),
    ([{"name": "a", "bounds": [[0, 0], [1, 1]]}], "bounds must be"),
    ([{"name": "a", "triangles": -1}], "triangles must be"),
    ([{"name": "a", "scale": [0, 1, 1]}], "scale"),
    ([{"name": "a"}, {"name": "a"}], "used twice"),
    ([], "at least one object"),
])
def test_bad_objects_from_a_node_are_refused(objects, message):
    with pytest.raises(SceneStateError, match=message):
        ObjectGraph.from_json(objects)
