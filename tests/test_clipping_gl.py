"""Clip planes, section boxes, caps and the highlight drawn on real GL (llvmpipe, issue 35): tiles
still equal the whole frame, culling the chunks a cut removes changes no pixel, cut faces are capped
in the cap colour, the highlight tints its object only, and ``--render-once --clip`` refuses a bad file."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from node.culling.switch import CullMode
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.gl.view_tools import ViewTools
from node.scene.builtin import build_builtin_scene
from node.scene.loading import load_scene
from tessera.geometry import Camera, Rect, default_camera
from tessera.scene.state import ObjectPatch
from tessera.scheduling.refinement import subsample
from tessera.tools.clipping import ClipState
from tests.conftest import PYTHON, REPO, scene_path, seconds

pytestmark = pytest.mark.gl

SIZE = (200, 150)
TILES = [Rect(0, 0, 73, 150), Rect(73, 0, 127, 61), Rect(73, 61, 127, 89)]


@pytest.fixture(scope="module")
def bunny():
    return load_scene(str(scene_path("bunny/bun_zipper.ply")))


def section(bounds: np.ndarray, planes: int) -> ClipState:
    """A box over the lower left part of ``bounds`` and ``planes`` planes through its middle (a box
    with three planes or more needs the discard path: 6 + planes > 8 clip distances)."""
    lo, hi = bounds
    mid = (lo + hi) / 2
    normals = [[-1, 0, 0], [0, -1, 0], [-0.3, -0.2, -1], [0.2, -1, 0.1], [-1, -1, 0], [0, 0.1, -1]]
    return ClipState.from_json({
        "planes": [{"point": (mid + 0.1 * k * (hi - lo)).tolist(), "normal": normals[k]} for k in range(planes)],
        "box": {"min": (lo - 1.0).tolist(), "max": (mid + 0.3 * (hi - lo)).tolist()}})


def tiled(renderer: TileRenderer, camera: Camera, **kwargs) -> np.ndarray:
    frame = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    for rect in TILES:
        frame[rect.y:rect.y1, rect.x:rect.x1] = renderer.render_tile(camera, SIZE, rect, **kwargs).pixels
    return frame


@pytest.mark.parametrize("planes", [2, 5])
def test_clipped_tiles_equal_the_clipped_frame(ctx, bunny, planes: int) -> None:
    renderer = TileRenderer(ctx, bunny)
    try:
        camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
        whole = renderer.render_frame(camera, SIZE).pixels
        renderer.use_tools(ViewTools(section(bunny.bounds, planes)))
        assert renderer.view.discards == (planes > 2)
        clipped = renderer.render_frame(camera, SIZE)
        assert np.array_equal(tiled(renderer, camera), clipped.pixels)
        sample = subsample(3, 8)
        assert np.array_equal(tiled(renderer, camera, subsample=sample),
                              renderer.render_frame(camera, SIZE, subsample=sample).pixels)
        assert not np.array_equal(clipped.pixels, whole)
        renderer.use_tools(None)
        assert np.array_equal(renderer.render_frame(camera, SIZE).pixels, whole)
    finally:
        renderer.release()


def test_half_spaces_beyond_the_clip_distances_cut_per_fragment(ctx, bunny) -> None:
    """A box's last face is the 11th half-space behind three planes that keep everything: it cuts
    by fragment discards as the box alone cuts by clip distances (to within edge pixels)."""
    renderer = TileRenderer(ctx, bunny, shading=ShadingOptions(msaa=1))
    try:
        camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
        lo, hi = bunny.bounds
        box = {"min": (lo - 1.0).tolist(), "max": [hi[0] + 1.0, hi[1] + 1.0, float((lo[2] + hi[2]) / 2)]}
        far = [{"point": (lo - 5.0).tolist(), "normal": normal} for normal in ([1, 0, 0], [0, 1, 0], [0, 0, 1])]
        renderer.use_tools(ViewTools(ClipState.from_json({"box": box})))
        by_distances = renderer.render_frame(camera, SIZE).pixels
        renderer.use_tools(ViewTools(ClipState.from_json({"box": box, "planes": far})))
        assert renderer.view.discards
        by_discards = renderer.render_frame(camera, SIZE).pixels
        renderer.use_tools(None)
        whole = renderer.render_frame(camera, SIZE).pixels
        differ = np.any(by_discards != by_distances, axis=2).mean()
        assert differ < 0.01 and np.any(by_discards != whole, axis=2).mean() > 0.05, differ
    finally:
        renderer.release()


def test_culling_what_is_cut_away_changes_no_pixel(ctx, bunny) -> None:
    culled, unculled = TileRenderer(ctx, bunny), TileRenderer(ctx, bunny, culling=CullMode.OFF)
    try:
        camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
        lo, hi = bunny.bounds
        quarter = ClipState.from_json({"box": {"min": lo.tolist(), "max": (lo + 0.4 * (hi - lo)).tolist()}})
        full = culled.render_frame(camera, SIZE)
        for renderer in (culled, unculled):
            renderer.use_tools(ViewTools(quarter))
        cut, reference = culled.render_frame(camera, SIZE), unculled.render_frame(camera, SIZE)
        assert np.array_equal(cut.pixels, reference.pixels)
        assert cut.triangles < 0.5 * full.triangles, (cut.triangles, full.triangles)
        assert reference.triangles == bunny.triangle_count
        hybrid = cut.chunks_drawn
        layer = culled.render_layer(camera, SIZE, Rect(0, 0, *SIZE), np.arange(bunny.chunks.chunk_count))
        assert layer.chunks_drawn == hybrid and np.array_equal(layer.pixels, unculled.render_layer(
            camera, SIZE, Rect(0, 0, *SIZE), np.arange(bunny.chunks.chunk_count)).pixels)
    finally:
        culled.release()
        unculled.release()


def test_cut_faces_are_capped_in_the_cap_colour(ctx, bunny) -> None:
    renderer = TileRenderer(ctx, bunny, shading=ShadingOptions(msaa=1))
    try:
        camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
        mid = bunny.bounds.mean(axis=0)
        facing = np.asarray(camera.eye) - mid
        plane = {"point": mid.tolist(), "normal": (-facing).tolist()}   # cuts away the half facing the eye
        color = [0.1, 0.9, 0.3]
        renderer.use_tools(ViewTools(ClipState.from_json({"planes": [plane], "cap_color": color})))
        capped = renderer.render_frame(camera, SIZE).pixels
        renderer.use_tools(ViewTools(ClipState.from_json({"planes": [plane], "cap": False})))
        open_cut = renderer.render_frame(camera, SIZE).pixels
        cap = np.all(capped == np.rint(np.asarray(color) * 255).astype(np.uint8), axis=2)
        assert cap.sum() > 0.05 * SIZE[0] * SIZE[1], cap.sum()
        assert not np.all(open_cut == np.rint(np.asarray(color) * 255).astype(np.uint8), axis=2).any()
        assert np.array_equal(capped[~cap], open_cut[~cap])
        renderer.use_tools(ViewTools(ClipState.from_json({"box": {"min": [9, 9, 9], "max": [10, 10, 10]}})))
        empty = renderer.render_frame(camera, SIZE)
        background = np.rint(np.asarray(renderer.background) * 255).astype(np.uint8)
        assert empty.triangles == 0 and np.all(empty.pixels == background)
    finally:
        renderer.release()


def test_highlight_tints_the_selected_object_only(ctx) -> None:
    scene = build_builtin_scene("spheres")
    renderer = TileRenderer(ctx, scene, shading=ShadingOptions(msaa=1))
    try:
        camera = default_camera(scene.bounds, aspect=SIZE[0] / SIZE[1])
        plain = renderer.render_frame(camera, SIZE).pixels
        hidden = renderer.render_frame(camera, SIZE, scene.state_at(0.0, {"sphere1": ObjectPatch(visible=False)}))
        sphere = np.any(plain != hidden.pixels, axis=2)
        renderer.use_tools(ViewTools(highlight="sphere1"))
        tinted = renderer.render_frame(camera, SIZE).pixels
        changed = np.any(tinted != plain, axis=2)
        assert changed.sum() > 0.9 * sphere.sum() > 0
        assert not (changed & ~sphere).any()
        renderer.use_tools(ViewTools(highlight="nowhere"))   # a name the scene lacks tints nothing
        assert np.array_equal(renderer.render_frame(camera, SIZE).pixels, plain)
    finally:
        renderer.release()


def test_render_once_clip_file(tmp_path) -> None:
    bad = tmp_path / "clip.json"
    bad.write_text('{"box": {"min": [0, 0, 0], "max": [0, 1, 1]}}')
    result = subprocess.run([PYTHON, "-m", "node", "--render-once", str(tmp_path / "out.png"), "--scene",
                             "builtin:spheres", "--size", "64x48", "--clip", str(bad)],
                            cwd=REPO, capture_output=True, text=True, timeout=seconds(120))
    assert result.returncode == 1 and f"error: clip file {bad}: box min must be below box max" in result.stderr
