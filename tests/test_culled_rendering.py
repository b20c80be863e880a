"""Sort-first without redundant geometry, on llvmpipe (seeds 002 §3.4, 001 §6): the octree pre-split
never changes the image, culling never drops a visible chunk (every culling mode draws exactly the
unculled pixels over many random cameras and tiles), the per-tile counters add up, the hybrid switch
runs per tile slot, and ``--render-once`` is the same image whatever the culling."""

from __future__ import annotations

import io
import json
import subprocess

import numpy as np
import pytest
from PIL import Image

from bench.images import psnr
from node.culling.switch import CullMode, SwitchParams, resolve_culling
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.loading import load_scene
from tessera.geometry import Camera, Rect, default_camera
from tests.conftest import PYTHON, REPO, scene_path, seconds
from tests.culling_support import random_cameras, random_tiles

pytestmark = pytest.mark.gl

SIZE = (160, 120)
FACE_LIMIT = 512
UNSPLIT = 1 << 40
#: one tile of a 4×4 grid, checked beside the random tiles
GRID_TILE = Rect(40, 30, 40, 30)
#: the random cameras: 0.3 to 3 half-diagonals of the scene's box away, fields of view up to 90°
NEAREST, WIDEST_DEG = 0.3, 90.0


@pytest.fixture(scope="module")
def bunny_spec() -> str:
    return str(scene_path("bunny/bun_zipper.ply"))


@pytest.fixture(scope="module")
def bunny(bunny_spec):
    return load_scene(bunny_spec, face_limit=FACE_LIMIT)


@pytest.fixture(scope="module")
def renderers(ctx, bunny):
    """One renderer of the split bunny per culling mode."""
    made = {mode: TileRenderer(ctx, bunny, culling=mode) for mode in CullMode}
    yield made
    for renderer in made.values():
        renderer.release()


@pytest.mark.parametrize(("relative", "face_limit"), [("bunny/bun_zipper.ply", FACE_LIMIT),
                                                      ("gltf_small/2CylinderEngine.glb", 64),
                                                      ("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf", 32)])
def test_pre_split_leaves_the_image_unchanged(ctx, relative, face_limit):
    spec = str(scene_path(relative))
    whole, split = load_scene(spec, face_limit=UNSPLIT), load_scene(spec, face_limit=face_limit)
    assert split.chunks.chunk_count > 2 * whole.chunks.chunk_count
    # At one sample: the pre-split draws triangles in another order, and with MSAA's four depth
    # samples per pixel the engine's coplanar faces tie somewhere (culling never reorders a draw).
    plain = TileRenderer(ctx, whole, culling=CullMode.OFF, shading=ShadingOptions(msaa=1))
    chunked = TileRenderer(ctx, split, culling=CullMode.OFF, shading=ShadingOptions(msaa=1))
    lo, hi = whole.bounds
    close = Camera(eye=tuple((lo + hi) / 2 + (hi - lo) * np.array([0.45, 0.3, 0.5])), target=tuple((lo + hi) / 2))
    cameras = [default_camera(whole.bounds), close,
               *random_cameras(whole.bounds, 3, seed=2, nearest=NEAREST, widest_deg=WIDEST_DEG)]
    for camera in cameras:
        reference = plain.render_frame(camera, SIZE).pixels
        image = chunked.render_frame(camera, SIZE).pixels
        assert psnr(image, reference) >= 50.0
        # Only exactly coplanar overlapping triangles could tell the draw orders apart; these scenes have none.
        assert np.array_equal(image, reference)
    plain.release()
    chunked.release()


def test_culling_draws_exactly_the_unculled_pixels_over_random_cameras_and_tiles(renderers, bunny):
    rng = np.random.default_rng(5)
    off = renderers[CullMode.OFF]
    chunk_total = bunny.chunks.chunk_count
    culled_tiles = visible_tiles = 0
    for camera in random_cameras(bunny.bounds, 10, seed=9, nearest=NEAREST, widest_deg=WIDEST_DEG):
        for slot, rect in enumerate(random_tiles(rng, 8, SIZE, [GRID_TILE])):
            reference = off.render_tile(camera, SIZE, rect, slot)
            assert (reference.cull_path, reference.chunks_drawn, reference.triangles) == \
                ("off", chunk_total, bunny.triangle_count)
            drawn = {}
            for mode in (CullMode.CPU, CullMode.GPU, CullMode.HYBRID):
                tile = renderers[mode].render_tile(camera, SIZE, rect, slot)
                assert np.array_equal(tile.pixels, reference.pixels), f"{mode.value} culling changed {rect} {camera}"
                assert tile.chunks_drawn + tile.chunks_culled == chunk_total
                assert 0 <= tile.triangles <= bunny.triangle_count and tile.cull_ms >= 0.0
                drawn[mode] = (tile.chunks_drawn, tile.triangles)
            assert drawn[CullMode.CPU] == drawn[CullMode.GPU], "the GPU kept other chunks than the CPU"
            chunks_drawn, triangles = drawn[CullMode.CPU]
            shows_model = bool((reference.pixels != reference.pixels[:1, :1]).any())
            if shows_model:
                assert triangles > 0 and chunks_drawn > 0
                visible_tiles += 1
            culled_tiles += chunks_drawn < chunk_total
    assert visible_tiles >= 20 and culled_tiles >= 40  # the cameras see the model, and culling culls


def test_one_draw_per_run_gives_the_multi_draw_pixels(ctx, bunny, renderers):
    """The GL < 4.3 fallback: the same runs, one draw call each."""
    rng = np.random.default_rng(3)
    for mode in (CullMode.CPU, CullMode.OFF):
        single = TileRenderer(ctx, bunny, culling=mode)
        single.multi_draw = False
        for camera in random_cameras(bunny.bounds, 3, seed=4, nearest=NEAREST, widest_deg=WIDEST_DEG):
            for rect in random_tiles(rng, 4, SIZE, [GRID_TILE]):
                expected = renderers[mode].render_tile(camera, SIZE, rect)
                tile = single.render_tile(camera, SIZE, rect)
                assert np.array_equal(tile.pixels, expected.pixels)
                assert (tile.triangles, tile.chunks_drawn) == (expected.triangles, expected.chunks_drawn)
        single.release()


def test_hybrid_switch_runs_per_tile_slot(ctx, bunny):
    switching = SwitchParams(threshold_s=1e-12, frames_to_switch=3, gpu_frames=4, check_frames=2)
    renderer = TileRenderer(ctx, bunny, culling=CullMode.HYBRID, switch_params=switching)
    never = TileRenderer(ctx, bunny, culling=CullMode.HYBRID, switch_params=SwitchParams(threshold_s=1e3))
    off = TileRenderer(ctx, bunny, culling=CullMode.OFF)
    camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
    left, right = Rect(0, 0, 80, 120), Rect(80, 0, 80, 120)
    paths = {"left": [], "right": []}
    for frame in range(10):
        for name, rect in (("left", left), ("right", right)):
            if name == "right" and frame < 3:
                continue   # the right slot starts three frames later: its switch is its own
            tile = renderer.render_tile(camera, SIZE, rect, slot=name)
            paths[name].append(tile.cull_path)
            assert np.array_equal(tile.pixels, off.render_tile(camera, SIZE, rect).pixels)
            assert never.render_tile(camera, SIZE, rect, slot=name).cull_path == "cpu"
    cpu, gpu = "cpu", "gpu"
    assert paths["left"] == [cpu] * 3 + [gpu] * 4 + [cpu] + [gpu] * 2   # bottleneck at once; back; doubled
    assert paths["right"] == [cpu] * 3 + [gpu] * 4
    for made in (renderer, never, off):
        made.release()


def render_once(tmp_path, name: str, *args: str) -> np.ndarray:
    result = subprocess.run([PYTHON, "-m", "node", "--render-once", str(tmp_path / name), *args], cwd=REPO,
                            capture_output=True, text=True, timeout=seconds(120))
    assert result.returncode == 0, result.stderr
    return np.asarray(Image.open(io.BytesIO((tmp_path / name).read_bytes())).convert("RGB"))


def test_render_once_is_the_same_image_with_any_culling(tmp_path, bunny_spec, renderers):
    camera = {"eye": [0.02, 0.14, 0.16], "target": [-0.03, 0.11, 0.0], "fovy_deg": 40}   # close: much is culled
    (tmp_path / "camera.json").write_text(json.dumps(camera))
    args = ("--scene", bunny_spec, "--camera", str(tmp_path / "camera.json"), "--size", "160x120", "--interactive")
    reference = render_once(tmp_path, "off.png", *args, "--culling", "off", "--face-limit", str(UNSPLIT))
    assert (reference != reference[0, 0]).any(axis=2).mean() > 0.2
    for mode in ("hybrid", "cpu", "gpu"):
        image = render_once(tmp_path, f"{mode}.png", *args, "--culling", mode, "--face-limit", str(FACE_LIMIT))
        assert np.array_equal(image, reference), f"--culling {mode} changed the reference image"
    assert np.array_equal(renderers[CullMode.GPU].render_frame(Camera.from_json(camera), SIZE).pixels, reference)


def test_default_culling_is_auto_resolved_for_the_context(ctx, bunny):
    """The renderer's default culling runs what ``auto`` means for this GL renderer (the CPU on
    llvmpipe), and a tile says so."""
    renderer = TileRenderer(ctx, bunny)
    expected = resolve_culling(CullMode.AUTO, ctx.info["GL_RENDERER"])
    assert renderer.culler.mode is expected and expected is not CullMode.AUTO
    camera = default_camera(bunny.bounds, aspect=SIZE[0] / SIZE[1])
    tile = renderer.render_tile(camera, SIZE, Rect(0, 0, 80, 120), "left")
    assert tile.cull_path in (("cpu",) if expected is CullMode.CPU else ("cpu", "gpu"))
    renderer.release()
