"""Depth layers on llvmpipe (seed 000 §4.4 and sort-last): a chunk straddling a tile edge is drawn
by its owner alone, into the strip, and the merged layers equal the whole render; the same for
hybrid tiles and sort-last shares of a real scan; a layer's colour is the tile's and its depth is
far exactly where nothing was drawn."""

from __future__ import annotations

import numpy as np
import pytest

from node.gl.depth_layers import PlanningScene, as_depth_layer, chunk_bounds, hybrid_plan, sort_last_plan
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.builtin import place, sphere
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.mesh import MeshBatch
from tessera.balancers.partition import equal_strip_partition
from tessera.compositing.depth_merge import merge_by_depth
from tessera.compositing.layers import FAR, background_pixel, split_layer
from tessera.decomposition.chunk_ownership import SHARED, assign_chunks
from tessera.decomposition.data_partition import split_chunks
from tessera.geometry import Camera, Rect, default_camera
from tests.conftest import scene_path

pytestmark = pytest.mark.gl

SIZE = (160, 120)
#: two tiles side by side, cut at x = 80
HALVES = [Rect(0, 0, 80, 120), Rect(80, 0, 80, 120)]
STRIP = 8

#: Depth layers are drawn at one sample (node.gl.renderer); so is the whole frame they compose.
ONE_SAMPLE = ShadingOptions(msaa=1)


def straddling_scene() -> SceneData:
    """A wall (2 triangles, wider than any strip) behind two small spheres, one chunk each: sphere
    ``near`` just left of the screen's middle and in front, ``far`` just right of it and behind,
    overlapping on screen."""
    positions = np.array([[-3, -2, -1], [3, -2, -1], [3, 2, -1], [-3, 2, -1]], np.float32)
    wall = MeshBatch("wall", positions, np.tile(np.array([0, 0, 1], np.float32), (4, 1)),
                     np.array([[0, 1, 2], [0, 2, 3]], np.uint32), base_color=np.array([0.3, 0.4, 0.5, 1], np.float32))
    ball = sphere(8, 16)
    near = place("near", ball, np.full(3, 0.2), np.identity(3), np.array([-0.06, 0.0, 0.5]), (0.9, 0.2, 0.1))
    far = place("far", ball, np.full(3, 0.2), np.identity(3), np.array([0.1, 0.25, 0.0]), (0.1, 0.8, 0.2))
    return SceneData.from_batches("straddling", [wall, near, far], face_limit=10_000)


CAMERA = Camera(eye=(0.0, 0.0, 4.0), target=(0.0, 0.0, 0.0), fovy_deg=60.0, near=0.5, far=10.0)


def planning(renderer: TileRenderer) -> PlanningScene:
    """The chunks of ``renderer``'s scene as the planners read them."""
    return PlanningScene.of(renderer.scene, renderer.culler.bvh)


@pytest.fixture(scope="module")
def straddling(ctx):
    renderer = TileRenderer(ctx, straddling_scene(), shading=ONE_SAMPLE)
    yield renderer
    renderer.release()


@pytest.fixture(scope="module")
def bunny(ctx):
    renderer = TileRenderer(ctx, load_scene(str(scene_path("bunny/bun_zipper.ply")), face_limit=512),
                            shading=ONE_SAMPLE)
    yield renderer
    renderer.release()


def bunny_cameras(scene: SceneData) -> list[Camera]:
    """The default view, a close-up that cuts the model at the frame's edges, and one from above."""
    default = default_camera(scene.bounds, aspect=SIZE[0] / SIZE[1])
    centre = scene.bounds.mean(axis=0)
    eye = np.asarray(default.eye)
    return [default, Camera(eye=tuple(centre + (eye - centre) * 0.45), target=tuple(centre), fovy_deg=45.0),
            Camera(eye=tuple(centre + np.array([0.05, 0.25, 0.06])), target=tuple(centre), fovy_deg=50.0)]


def test_a_chunk_straddling_a_tile_edge_composes_identically_to_the_whole_render(straddling):
    renderer = straddling
    ids = np.arange(renderer.scene.chunks.chunk_count)
    chunks = planning(renderer)
    bounds = chunk_bounds(chunks, ids, CAMERA, SIZE)
    wall, near, far = 0, 1, 2
    assert bounds[near, 0] < 80 < bounds[near, 2] and bounds[far, 0] < 80 < bounds[far, 2], "both spheres straddle"
    ownership = assign_chunks(bounds, HALVES, STRIP, SIZE)
    assert ownership.owner.tolist() == [SHARED, 0, 1]

    plans = [hybrid_plan(chunks, CAMERA, SIZE, HALVES, index, STRIP) for index in range(2)]
    assert [plan.chunk_ids.tolist() for plan in plans] == [[wall, near], [wall, far]]
    assert [plan.rect for plan in plans] == [Rect(0, 0, 88, 120), Rect(72, 0, 88, 120)]
    assert [plan.exclusive for plan in plans] == [Rect(0, 0, 72, 120), Rect(88, 0, 72, 120)]
    layers = [renderer.render_layer(CAMERA, SIZE, plan.rect, plan.chunk_ids) for plan in plans]
    assert [layer.triangles for layer in layers] == [2 + 288, 2 + 288]

    whole = renderer.render_frame(CAMERA, SIZE).pixels
    merged = merge_by_depth([as_depth_layer(layer, slot) for slot, layer in enumerate(layers)], SIZE,
                       background_pixel(renderer.background))
    np.testing.assert_array_equal(merged, whole)
    # neither tile's own part is right alone: each sphere is drawn by its owner only, past the edge
    assert not np.array_equal(layers[0].pixels[:, :80], whole[:, :80])
    assert not np.array_equal(layers[1].pixels[:, 8:], whole[:, 80:])


def test_a_layer_is_the_tile_with_depth_far_exactly_where_nothing_was_drawn(bunny):
    camera = bunny_cameras(bunny.scene)[0]
    rect = Rect(30, 20, 90, 70)
    tile = bunny.render_tile(camera, SIZE, rect)
    layer = bunny.render_layer(camera, SIZE, rect)
    assert tile.depth is None and layer.depth is not None and layer.depth.dtype == np.float32
    np.testing.assert_array_equal(layer.pixels, tile.pixels)
    empty = layer.depth >= FAR
    assert 0.05 < empty.mean() < 0.95
    assert (layer.pixels[empty] == background_pixel(bunny.background)).all()
    assert layer.depth.min() >= 0.0


@pytest.mark.parametrize(("tiles", "strip"), [(2, 0), (4, 4), (6, 16)])
def test_hybrid_tiles_compose_the_whole_render(bunny, tiles, strip):
    rects = equal_strip_partition(tiles, SIZE)
    background = background_pixel(bunny.background)
    chunks = planning(bunny)
    for camera in bunny_cameras(bunny.scene):
        plans = [hybrid_plan(chunks, camera, SIZE, rects, index, strip) for index in range(tiles)]
        rendered = [bunny.render_layer(camera, SIZE, plan.rect, plan.chunk_ids) for plan in plans]
        whole = bunny.render_frame(camera, SIZE).pixels
        layers = [as_depth_layer(layer, slot) for slot, layer in enumerate(rendered)]
        np.testing.assert_array_equal(merge_by_depth(layers, SIZE, background), whole)
        # the seed's way: depth only in the strips, each tile's core as colour alone
        strips, cores = [], []
        for layer, plan in zip(layers, plans, strict=True):
            pieces, core_color = split_layer(layer, plan.exclusive)
            strips += pieces
            if plan.exclusive is not None and core_color is not None:
                cores.append((plan.exclusive, core_color))
        np.testing.assert_array_equal(merge_by_depth(strips, SIZE, background, cores), whole)


@pytest.mark.parametrize("weights", [[1.0, 1.0], [1.0, 2.0, 1.0], [1.0, 1.0, 1.0, 1.0]])
def test_sort_last_shares_compose_the_whole_render(bunny, weights):
    chunks = bunny.scene.chunks
    share_of = split_chunks(chunks.boxes, chunks.face_counts, weights)
    background = background_pixel(bunny.background)
    held = planning(bunny)
    for camera in bunny_cameras(bunny.scene):
        plans = [sort_last_plan(held, camera, SIZE, np.flatnonzero(share_of == node)) for node in range(len(weights))]
        layers = [as_depth_layer(bunny.render_layer(camera, SIZE, plan.rect, plan.chunk_ids), slot)
                  for slot, plan in enumerate(plans) if plan is not None]
        whole = bunny.render_frame(camera, SIZE)
        assert sum(plan.chunk_ids.size for plan in plans if plan is not None) == whole.chunks_drawn
        np.testing.assert_array_equal(merge_by_depth(layers, SIZE, background), whole.pixels)


def test_a_layer_with_no_chunks_is_all_far(bunny):
    camera = bunny_cameras(bunny.scene)[0]
    layer = bunny.render_layer(camera, SIZE, Rect(10, 10, 40, 30), np.zeros(0, np.int64))
    assert layer.triangles == 0 and layer.chunks_drawn == 0 and layer.cull_path == "list"
    assert layer.depth is not None and (layer.depth == FAR).all()
    assert (merge_by_depth([as_depth_layer(layer, 0)], SIZE, background_pixel(bunny.background))
            == background_pixel(bunny.background)).all()
