"""Rendering a scene state on real GL (issue 11): moved, turned, scaled and hidden objects render
identically in a tile and in the whole frame under every culling mode, and a moved object is culled
where it is now; CesiumMilkTruck's wheel animation changes only the wheels, and ``--render-once
--time`` equals a hand-posed ``--objects``."""

from __future__ import annotations

import io
import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from node.culling.switch import CullMode
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.loading import load_scene
from tessera.geometry import Rect, default_camera
from tessera.scene.state import ObjectPatch
from tests.conftest import PYTHON, REPO, scene_path, seconds

pytestmark = pytest.mark.gl

SIZE = (320, 240)
#: Halves, quarters, slivers and odd tiles; the right half holds sphere0's new place, not its old one.
RECTS = [Rect(160, 0, 160, 240), Rect(0, 0, 160, 240), Rect(37, 51, 101, 77), Rect(111, 13, 209, 227),
         Rect(319, 0, 1, 240), Rect(0, 239, 320, 1), Rect(161, 121, 159, 119)]
TRUCK = "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"
#: The truck's wheel nodes (unnamed in the file: trimesh's names are their indices).
WHEELS = ("2", "4")
S30 = math.sin(math.radians(30))


@pytest.fixture(scope="module")
def spheres():
    return load_scene("builtin:spheres", face_limit=64)


@pytest.fixture(scope="module")
def truck():
    return load_scene(str(scene_path(TRUCK)))


@pytest.fixture(scope="module")
def renderers(ctx, spheres, truck):
    # One sample: depth layers are drawn at one, and they are compared with whole frames here.
    made = {mode: TileRenderer(ctx, spheres, culling=mode, shading=ShadingOptions(msaa=1))
            for mode in (CullMode.OFF, CullMode.CPU, CullMode.GPU)}
    made["truck"] = TileRenderer(ctx, truck, culling=CullMode.CPU)
    yield made
    for renderer in made.values():
        renderer.release()


def moved_state(scene):
    """sphere0 carried from the left to the right, turned 60° about x and grown; sphere2 hidden."""
    return scene.state_at(0.0, {
        "sphere0": ObjectPatch(translation=(2.5, 0.3, 0.0), rotation=(S30, 0.0, 0.0, math.cos(math.radians(30))),
                               scale=(1.5, 1.0, 1.5)),
        "sphere2": ObjectPatch(visible=False),
    })


@pytest.mark.parametrize("mode", [CullMode.OFF, CullMode.CPU, CullMode.GPU])
def test_moved_objects_render_identically_in_a_tile_and_the_whole_frame(renderers, spheres, mode):
    renderer = renderers[mode]
    camera = default_camera(spheres.bounds, aspect=SIZE[0] / SIZE[1])
    state = moved_state(spheres)
    whole = renderer.render_frame(camera, SIZE, state).pixels
    assert not np.array_equal(whole, renderer.render_frame(camera, SIZE).pixels)
    for number, rect in enumerate(RECTS):
        tile = renderer.render_tile(camera, SIZE, rect, slot=number, state=state)
        assert np.array_equal(tile.pixels, whole[rect.y:rect.y1, rect.x:rect.x1]), f"{mode.value} tile {rect}"
    # Every culling mode draws the same picture of the state.
    assert np.array_equal(whole, renderers[CullMode.OFF].render_frame(camera, SIZE, state).pixels)


def test_moved_object_shows_where_it_went(renderers, spheres):
    renderer = renderers[CullMode.CPU]
    camera = default_camera(spheres.bounds, aspect=SIZE[0] / SIZE[1])
    state = moved_state(spheres)
    gone = spheres.state_at(0.0, {"sphere0": ObjectPatch(visible=False), "sphere2": ObjectPatch(visible=False)})
    # The right half with and without sphere0: it is there now (its chunks' boxes are still on the left).
    right = RECTS[0]
    with_it = renderer.render_tile(camera, SIZE, right, slot="r", state=state).pixels
    without = renderer.render_tile(camera, SIZE, right, slot="r", state=gone).pixels
    assert (with_it != without).any(axis=2).sum() > 200


@pytest.mark.parametrize("mode", [CullMode.CPU, CullMode.GPU])
def test_a_moved_object_is_culled_where_it_is_now(renderers, spheres, mode):
    renderer = renderers[mode]
    camera = default_camera(spheres.bounds, aspect=SIZE[0] / SIZE[1])
    state = moved_state(spheres)
    gone = spheres.state_at(0.0, {"sphere0": ObjectPatch(visible=False), "sphere2": ObjectPatch(visible=False)})
    sphere0 = spheres.objects.objects[spheres.objects.lookup("sphere0")].triangles

    def extra(rect):
        """Triangles sphere0 adds to the tile ``rect`` in its moved place."""
        moved = renderer.render_tile(camera, SIZE, rect, slot=("moved", rect), state=state)
        return moved.triangles - renderer.render_tile(camera, SIZE, rect, slot=("moved", rect), state=gone).triangles

    # It left the far left for the right half: culled there (its base-pose boxes are on the left), all drawn here.
    assert extra(Rect(0, 0, 80, 240)) == 0
    assert extra(RECTS[0]) == sphere0
    assert extra(RECTS[0]) > extra(RECTS[1]) and extra(Rect(0, 0, 320, 240)) == sphere0
    # Without culling every tile draws it whole.
    off = renderers[CullMode.OFF]
    assert off.render_tile(camera, SIZE, Rect(0, 0, 80, 240), state=state).triangles == \
        spheres.triangle_count - spheres.objects.objects[spheres.objects.lookup("sphere2")].triangles


@pytest.mark.parametrize("mode", [CullMode.CPU, CullMode.GPU])
def test_a_depth_layer_of_listed_chunks_culls_moved_objects_where_they_are_now(renderers, spheres, mode):
    """Hybrid and sort-last layers list their chunks by base-pose ownership; a moved object is drawn
    only where it is now, and the layer's picture is the whole frame's."""
    renderer = renderers[mode]
    camera = default_camera(spheres.bounds, aspect=SIZE[0] / SIZE[1])
    state = moved_state(spheres)
    sphere0 = spheres.objects.objects[spheres.objects.lookup("sphere0")].triangles
    none = np.zeros(0, np.int64)
    assert renderer.render_layer(camera, SIZE, Rect(0, 0, 80, 240), none, state=state).triangles == 0
    assert renderer.render_layer(camera, SIZE, RECTS[0], none, state=state).triangles == sphere0
    whole = renderer.render_frame(camera, SIZE, state).pixels
    every_chunk = np.arange(spheres.chunks.chunk_count)
    for rect in RECTS:
        layer = renderer.render_layer(camera, SIZE, rect, every_chunk, state=state)
        assert np.array_equal(layer.pixels, whole[rect.y:rect.y1, rect.x:rect.x1]), f"{mode.value} layer {rect}"


def test_the_base_state_draws_the_static_scene_and_counts_what_it_draws(renderers, spheres):
    renderer = renderers[CullMode.OFF]
    camera = default_camera(spheres.bounds, aspect=SIZE[0] / SIZE[1])
    static = renderer.render_frame(camera, SIZE)
    base = renderer.render_frame(camera, SIZE, spheres.state_at(0.0))
    assert np.array_equal(static.pixels, base.pixels)
    assert (base.triangles, base.chunks_culled) == (spheres.triangle_count, 0)
    moved = renderer.render_frame(camera, SIZE, moved_state(spheres))
    hidden = spheres.objects.objects[spheres.objects.lookup("sphere2")]
    assert moved.triangles == spheres.triangle_count - hidden.triangles
    assert moved.chunks_drawn + moved.chunks_culled == spheres.chunks.chunk_count and moved.chunks_culled > 0


def test_truck_wheel_animation_changes_only_the_wheels(renderers, truck):
    renderer = renderers["truck"]
    camera = default_camera(truck.bounds, aspect=SIZE[0] / SIZE[1])
    hide = {name: ObjectPatch(visible=False) for name in WHEELS}

    def frame(time, overrides=None):
        return renderer.render_frame(camera, SIZE, truck.state_at(time, overrides)).pixels

    start, later = frame(0.0), frame(0.625)
    changed = (start != later).any(axis=2)
    wheels = (start != frame(0.0, hide)).any(axis=2) | (later != frame(0.625, hide)).any(axis=2)
    assert changed.sum() > 100
    assert not (changed & ~wheels).any(), "the animation changed pixels outside the wheels"
    assert np.array_equal(frame(5.0), frame(1.25))                   # clamped after the last keyframe


def render_once(tmp_path: Path, name: str, *args: str) -> np.ndarray:
    result = subprocess.run([PYTHON, "-m", "node", "--render-once", str(tmp_path / name), "--size", "160x120",
                             *args], cwd=REPO, capture_output=True, text=True, timeout=seconds(120))
    assert result.returncode == 0, result.stderr
    return np.asarray(Image.open(io.BytesIO((tmp_path / name).read_bytes())).convert("RGB"))


def test_render_once_at_a_time_equals_the_hand_posed_state(tmp_path):
    truck = str(scene_path(TRUCK))
    # At its last keyframe (1.25 s) the animation turns both wheels to the identity rotation.
    upright = {name: {"rotation": [0, 0, 0, 1]} for name in WHEELS}
    (tmp_path / "upright.json").write_text(json.dumps(upright))
    animated = render_once(tmp_path, "animated.png", "--scene", truck, "--time", "1.25")
    posed = render_once(tmp_path, "posed.png", "--scene", truck, "--objects", str(tmp_path / "upright.json"))
    assert np.array_equal(animated, posed)
    # Keyframe 15 (0.625 s), its quaternion read straight from the buffer (accessor 15: view 4 at 0).
    raw = (scene_path(TRUCK).parent / "CesiumMilkTruck0.bin").read_bytes()
    quaternion = np.frombuffer(raw, "<f4", count=4, offset=15 * 16).tolist()
    (tmp_path / "keyframe.json").write_text(json.dumps({name: {"rotation": quaternion} for name in WHEELS}))
    animated = render_once(tmp_path, "t0625.png", "--scene", truck, "--time", "0.625")
    posed = render_once(tmp_path, "k15.png", "--scene", truck, "--objects", str(tmp_path / "keyframe.json"))
    assert np.array_equal(animated, posed)
    assert not np.array_equal(animated, render_once(tmp_path, "t0.png", "--scene", truck))


def test_render_once_names_a_bad_objects_file(tmp_path):
    truck = str(scene_path(TRUCK))
    for content, message in [({"wheel": {"visible": False}}, "unknown object 'wheel'; the scene's objects are 0, 3"),
                             ({"2": {"scale": [1, 0, 1]}}, "2.scale must be non-zero")]:
        (tmp_path / "state.json").write_text(json.dumps(content))
        result = subprocess.run([PYTHON, "-m", "node", "--render-once", str(tmp_path / "out.png"), "--scene", truck,
                                 "--objects", str(tmp_path / "state.json")], cwd=REPO, capture_output=True, text=True,
                                timeout=seconds(120))
        assert result.returncode == 1 and message in result.stderr, result.stderr


@pytest.mark.parametrize("mode", [CullMode.OFF, CullMode.CPU, CullMode.GPU])
def test_traffic_tiles_equal_the_whole_frame_while_cars_move(ctx, mode):
    scene = load_scene("builtin:traffic")
    renderer = TileRenderer(ctx, scene, culling=mode)
    camera = default_camera(scene.bounds, aspect=SIZE[0] / SIZE[1])
    frames = []
    for time in (0.0, 2.3):
        state = scene.state_at(time)
        whole = renderer.render_frame(camera, SIZE, state).pixels
        for number, rect in enumerate(RECTS[:4]):
            tile = renderer.render_tile(camera, SIZE, rect, slot=number, state=state).pixels
            assert np.array_equal(tile, whole[rect.y:rect.y1, rect.x:rect.x1]), f"t={time} tile {rect}"
        frames.append(whole)
    assert (frames[0] != frames[1]).any(axis=2).mean() > 0.02
    if mode is not CullMode.OFF:   # a quarter tile draws fewer of the moved cars' triangles than the frame
        quarter = renderer.render_tile(camera, SIZE, Rect(0, 0, 160, 120), slot="q", state=state)
        assert quarter.triangles < renderer.render_frame(camera, SIZE, state).triangles
    renderer.release()
