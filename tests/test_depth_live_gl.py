"""The live depth modes' node half on llvmpipe, in one process (issue 10): a sort-last node keeps
only its share (every triangle in exactly one share, the whole scene's bounds kept), and what the
nodes send — planned by :func:`node.gl.depth_layers.live_plan`, drawn, encoded as depth tiles,
checked and decoded by the coordinator's reader, merged — equals the whole render bit for bit,
for sort-last shares held by separate renderers and for hybrid tiles of a scene with blended
geometry."""

from __future__ import annotations

import numpy as np
import pytest

from node.gl.depth_layers import PlanningScene, live_plan, render_plan
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.loading import load_scene
from node.scene.shares import keep_share
from tessera.compositing.depth_merge import merge_depth_tiles
from tessera.compositing.layers import BlendLayer, DepthLayer, background_pixel
from tessera.decomposition.chunk_ownership import exclusive_rect, readback_rect
from tessera.decomposition.data_partition import split_chunks
from tessera.decomposition.hybrid import hybrid_frame_tiles
from tessera.geometry import Rect, default_camera
from tessera.scene.state import ObjectPatch
from tessera.wire.codec import Codec, decode
from tessera.wire.depth_tiles import encode_depth_tile, read_depth_tile
from tessera.wire.messages import DepthRequest
from tests.conftest import scene_path

pytestmark = pytest.mark.gl

SIZE = (200, 150)
WEIGHTS = (1.0, 1.0, 2.0)

#: Depth layers are drawn at one sample (node.gl.renderer); so is the whole frame they compose.
ONE_SAMPLE = ShadingOptions(msaa=1)


@pytest.fixture(scope="module")
def bunny():
    return load_scene(str(scene_path("bunny/bun_zipper.ply")))


def test_each_triangle_lands_in_exactly_one_share(bunny):
    shares = [keep_share(bunny, WEIGHTS, index) for index in range(len(WEIGHTS))]
    share_of = split_chunks(bunny.chunks.boxes, bunny.chunks.face_counts, WEIGHTS)
    expected = [int(bunny.chunks.face_counts[share_of == i].sum()) for i in range(len(WEIGHTS))]
    assert [s.triangle_count for s in shares] == expected and sum(expected) == bunny.triangle_count
    assert expected[2] > expected[0], "the heavier weight holds more"

    def triangles(scene):
        return {tuple(np.round(b.positions[face].reshape(-1), 6)) for b in scene.batches for face in b.faces}

    assert set().union(*map(triangles, shares)) == triangles(bunny)
    for share in shares:
        assert np.array_equal(share.bounds, bunny.bounds) and share.objects is bunny.objects
        assert share.vertex_count < bunny.vertex_count, "only the vertices its faces use"


def planning(renderer: TileRenderer) -> PlanningScene:
    """The chunks of ``renderer``'s scene as the planners read them."""
    return PlanningScene.of(renderer.scene, renderer.culler.bvh)


def through_the_wire(layer, core, slot, bound, core_range):
    """What the coordinator keeps of a node's layer: encoded as a depth tile, read back."""
    depth_layer = None if layer is None else DepthLayer(layer.rect, layer.pixels, layer.depth, 0)
    return read_depth_tile(encode_depth_tile(depth_layer, core, Codec.PNG, 90)[0], bound, core_range, slot)


def test_sort_last_shares_on_their_own_renderers_merge_into_the_whole_render(ctx, bunny):
    camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
    whole_renderer = TileRenderer(ctx, bunny, shading=ONE_SAMPLE)
    whole = whole_renderer.render_frame(camera, SIZE).pixels
    background = background_pixel(whole_renderer.background)
    whole_renderer.release()
    request = DepthRequest(mode="sort-last", share=1)
    tiles = []
    for index in range(len(WEIGHTS)):
        renderer = TileRenderer(ctx, keep_share(bunny, WEIGHTS, index), shading=ONE_SAMPLE)
        plan = live_plan(planning(renderer), renderer.pose_of(None), camera, SIZE, request, 0)
        assert plan is not None and plan.rect.area < SIZE[0] * SIZE[1], "bounding-box read-back"
        layer = renderer.render_layer(camera, SIZE, plan.rect, plan.chunk_ids)
        tiles.append(through_the_wire(layer, None, index, Rect(0, 0, *SIZE), None))
        renderer.release()
    assert np.array_equal(merge_depth_tiles(tiles, SIZE, background), whole)


def test_hybrid_tiles_of_a_scene_with_blended_geometry_merge_into_the_whole_render(ctx):
    scene = load_scene(str(scene_path("multi_object/sd_macross_city_diorama.glb")))
    assert any(batch.alpha_mode == "BLEND" for batch in scene.batches)
    renderer = TileRenderer(ctx, scene, shading=ONE_SAMPLE)
    size, strip = (320, 240), 32
    rects = [Rect(0, 0, 176, 139), Rect(176, 0, 144, 139), Rect(0, 139, 320, 101)]
    request = DepthRequest(mode="hybrid", tiles=tuple(rects), strip=strip)
    chunks = planning(renderer)
    bounds = np.asarray(scene.bounds)
    for turn in (0.0, 2.1, 4.2):
        camera = default_camera(bounds, aspect=size[0] / size[1])
        eye = np.asarray(camera.eye) - np.asarray(camera.target)
        rotation = np.array([[np.cos(turn), 0, np.sin(turn)], [0, 1, 0], [-np.sin(turn), 0, np.cos(turn)]])
        camera = type(camera)(eye=tuple((rotation @ eye + camera.target).tolist()), target=camera.target,
                              up=camera.up, fovy_deg=camera.fovy_deg)
        whole = renderer.render_frame(camera, size).pixels
        decoded = []
        for index, rect in enumerate(rects):
            plan = live_plan(chunks, renderer.pose_of(None), camera, size, request, index)
            assert plan is not None
            layer = renderer.render_layer(camera, size, plan.rect, plan.chunk_ids)
            decoded.append(through_the_wire(layer, plan.exclusive, index, readback_rect(rect, strip, size),
                                            (exclusive_rect(rect, strip, size), rect)))
        merged = merge_depth_tiles(decoded, size, background_pixel(renderer.background))
        frame = np.zeros_like(whole)
        for region, _, data in hybrid_frame_tiles(list(zip(rects, decoded, strict=True)), merged, Codec.PNG, 90):
            frame[region.y:region.y1, region.x:region.x1] = decode(data, Codec.PNG, region.w, region.h)
        assert np.array_equal(frame, whole), f"turn {turn}"
    renderer.release()


def merge_shares(renderers, camera, size, state, background) -> tuple[np.ndarray, int]:
    """Sort-last as served: each share's renderer plans and draws its layer and blended fragments
    (:func:`render_plan`), they go through the wire and are merged; with the most blend layers
    any share peeled."""
    tiles, peeled = [], 0
    for index, renderer in enumerate(renderers):
        plan = live_plan(planning(renderer), renderer.pose_of(state), camera, size,
                         DepthRequest(mode="sort-last", share=1), 0)
        assert plan is not None
        layer, fragments = render_plan(renderer, camera, size, plan, state)
        blend = None
        if fragments is not None and fragments.depth.shape[0]:
            peeled = max(peeled, fragments.depth.shape[0])
            blend = BlendLayer(layer.rect, fragments.color, fragments.alpha, fragments.depth, 0)
        payload = encode_depth_tile(DepthLayer(layer.rect, layer.pixels, layer.depth, 0), None, Codec.PNG, 90, 1,
                                    blend)[0]
        tiles.append(read_depth_tile(payload, Rect(0, 0, *size), None, index))
    return merge_depth_tiles(tiles, size, background), peeled


def test_blended_fragments_peeled_and_laid_over_the_merge_equal_blending_in_place(ctx):
    """The diorama's scene-wide glass mesh in three shares: each node peels its blended fragments in
    front of its own layer and accumulates them in draw order, and the compositor lays over each
    pixel those in front of the merged surface: the frame GL blends in place, up to rounding (a
    level where blending rounds once instead of after each fragment)."""
    scene = load_scene(str(scene_path("multi_object/sd_macross_city_diorama.glb")))
    renderers = [TileRenderer(ctx, keep_share(scene, (1.0, 1.0, 1.0), index), shading=ONE_SAMPLE)
                 for index in range(3)]
    whole_renderer = TileRenderer(ctx, scene, shading=ONE_SAMPLE)
    size = (320, 240)
    camera = default_camera(np.asarray(scene.bounds), aspect=size[0] / size[1])
    whole = whole_renderer.render_frame(camera, size).pixels
    merged, peeled = merge_shares(renderers, camera, size, None, background_pixel(whole_renderer.background))
    assert peeled >= 2, "front and back faces of the glass"
    difference = np.abs(merged.astype(np.int16) - whole).max(axis=2)
    assert difference.max() <= 2 and (difference > 0).sum() > 0, "the glass is there, rounded once"
    for renderer in (*renderers, whole_renderer):
        renderer.release()


def test_a_moved_blended_object_in_sort_last_shares_is_blended_once(ctx):
    """The diorama moved as a whole (its one object): every batch is drawn where it is now, the
    glass among them; each share sends its opaque layer and its glass apart, as when nothing moved,
    so the merge equals the whole render of that state up to the blend's rounding."""
    scene = load_scene(str(scene_path("multi_object/sd_macross_city_diorama.glb")))
    (name,) = scene.objects.names
    extent = np.ptp(np.asarray(scene.bounds), axis=0)
    state = scene.state_at(0.0, {name: ObjectPatch(translation=tuple((0.08 * extent * (1, 0, -1)).tolist()))})
    renderers = [TileRenderer(ctx, keep_share(scene, (1.0, 1.0, 1.0), index), shading=ONE_SAMPLE)
                 for index in range(3)]
    whole_renderer = TileRenderer(ctx, scene, shading=ONE_SAMPLE)
    size = (320, 240)
    camera = default_camera(np.asarray(scene.bounds), aspect=size[0] / size[1])
    whole = whole_renderer.render_frame(camera, size, state).pixels
    assert not np.array_equal(whole, whole_renderer.render_frame(camera, size).pixels), "the state moves it"
    merged, peeled = merge_shares(renderers, camera, size, state, background_pixel(whole_renderer.background))
    assert peeled >= 2, "the glass's share peels its front and back faces"
    difference = np.abs(merged.astype(np.int16) - whole).max(axis=2)
    assert difference.max() <= 2, f"{int((difference > 2).sum())} pixels off by more than 2, up to {difference.max()}"
    for renderer in (*renderers, whole_renderer):
        renderer.release()
