"""Tile rendering on real GL (llvmpipe): tiles equal the full frame's pixels exactly, orientation,
background, two-sided lighting, textures, and the ``--render-once`` command line."""

from __future__ import annotations

import io
import json
import subprocess

import numpy as np
import pytest
from PIL import Image

from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.mesh import MeshBatch
from tessera.geometry import Camera, Rect, default_camera
from tests.conftest import PYTHON, REPO, scene_path, seconds

pytestmark = pytest.mark.gl

SIZE = (320, 240)
RECTS = [Rect(0, 0, 160, 120), Rect(37, 51, 101, 77), Rect(111, 13, 209, 227), Rect(319, 0, 1, 240),
         Rect(0, 239, 320, 1), Rect(1, 1, 317, 238), Rect(161, 121, 159, 119)]


@pytest.fixture(scope="module")
def renderers(ctx):
    made: dict[str, TileRenderer] = {}

    def get(spec: str) -> TileRenderer:
        if spec not in made:
            made[spec] = TileRenderer(ctx, load_scene(spec))
        return made[spec]

    yield get
    for renderer in made.values():
        renderer.release()


def cameras_for(scene: SceneData) -> list[Camera]:
    """The default camera, a close oblique one and one looking down at the scene."""
    lo, hi = scene.bounds
    centre, extent = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo))
    return [
        default_camera(scene.bounds),
        Camera(eye=tuple(centre + extent * np.array([0.5, 0.2, 0.45])),
               target=tuple(centre + np.array([0.0, extent * 0.05, 0.0])), fovy_deg=35.0),
        Camera(eye=tuple(centre + extent * np.array([-0.3, 1.1, 0.2])), target=tuple(centre), up=(0.0, 0.0, -1.0),
               fovy_deg=60.0),
    ]


def background_bytes(renderer: TileRenderer) -> np.ndarray:
    return np.rint(np.asarray(renderer.background) * 255.0).astype(np.uint8)


@pytest.mark.parametrize("relative", ["bunny/bun_zipper.ply", "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"])
def test_tile_equals_region_of_full_frame(renderers, relative):
    renderer = renderers(str(scene_path(relative)))
    for camera in cameras_for(renderer.scene):
        full = renderer.render_frame(camera, SIZE)
        assert full.pixels.shape == (SIZE[1], SIZE[0], 3) and full.pixels.dtype == np.uint8
        assert (full.pixels != background_bytes(renderer)).any(axis=2).mean() > 0.02, "the object is not in view"
        for rect in RECTS:
            tile = renderer.render_tile(camera, SIZE, rect)
            region = full.pixels[rect.y:rect.y1, rect.x:rect.x1]
            assert tile.pixels.shape == region.shape
            assert np.array_equal(tile.pixels, region), f"tile {rect.as_list()} differs from the full frame"


def test_tiles_of_an_odd_sized_frame_compose_the_full_frame(renderers):
    renderer = renderers(str(scene_path("gltf_small/Duck.glb")))
    size = (203, 147)
    camera = cameras_for(renderer.scene)[1]
    full = renderer.render_frame(camera, size).pixels
    stitched = np.zeros_like(full)
    for x0, x1 in ((0, 67), (67, 150), (150, 203)):
        for y0, y1 in ((0, 51), (51, 147)):
            stitched[y0:y1, x0:x1] = renderer.render_tile(camera, size, Rect(x0, y0, x1 - x0, y1 - y0)).pixels
    assert np.array_equal(stitched, full)


def test_rect_outside_the_frame_is_refused(renderers):
    renderer = renderers("builtin:spheres")
    with pytest.raises(ValueError, match="outside"):
        renderer.render_tile(default_camera(renderer.scene.bounds), (64, 48), Rect(60, 0, 8, 8))


def single_triangle_scene(normal_sign: float) -> SceneData:
    """One white triangle in the z = 0 plane, up and to the left of the origin."""
    positions = np.array([[-1.0, 0.2, 0.0], [-0.2, 0.2, 0.0], [-0.6, 1.0, 0.0]], dtype=np.float32)
    normals = np.tile(np.array([0.0, 0.0, normal_sign], dtype=np.float32), (3, 1))
    batch = MeshBatch("triangle", positions, normals, np.array([[0, 1, 2]], dtype=np.uint32),
                      base_color=np.ones(4, np.float32))
    return SceneData.from_batches("triangle", [batch])


@pytest.mark.parametrize("normal_sign", [1.0, -1.0])
def test_image_orientation_and_two_sided_lighting(ctx, normal_sign):
    renderer = TileRenderer(ctx, single_triangle_scene(normal_sign), background=(0.0, 0.0, 0.0),
                            shading=ShadingOptions(msaa=1))  # no edge pixels blended with the background
    camera = Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0), fovy_deg=60.0, near=0.1, far=10.0)
    pixels = renderer.render_frame(camera, (64, 64)).pixels
    renderer.release()
    lit = pixels.max(axis=2) > 0
    rows, cols = np.nonzero(lit)
    assert rows.max() < 32 and cols.max() < 32, "the triangle must be in the top-left quadrant"
    assert pixels[rows, cols].min() > 150, "a triangle seen from either side must be lit"


@pytest.mark.parametrize("background", [(0.0, 0.0, 0.0), (0.2, 0.4, 0.6), (1.0, 0.5, 0.25)])
def test_background_colour_is_honoured(ctx, background):
    renderer = TileRenderer(ctx, load_scene("builtin:spheres"), background=background)
    camera = default_camera(renderer.scene.bounds)
    pixels = renderer.render_tile(camera, (80, 60), Rect(0, 0, 80, 20)).pixels
    renderer.release()
    expected = np.rint(np.asarray(background) * 255.0).astype(np.uint8)
    assert np.array_equal(pixels[0, 0], expected) and np.array_equal(pixels[0, -1], expected)


def test_textured_gltf_shows_its_texture(renderers):
    renderer = renderers(str(scene_path("gltf_small/Duck.glb")))
    camera = cameras_for(renderer.scene)[0]
    pixels = renderer.render_frame(camera, (160, 120)).pixels
    inside = pixels[(pixels != background_bytes(renderer)).any(axis=2)]
    assert len(inside) > 1000
    assert len(np.unique(inside, axis=0)) > 100, "the duck is one flat colour: texture not sampled"
    red, green, blue = inside.astype(np.float64).mean(axis=0)
    assert red > blue + 60 and green > blue + 30, "the duck's texture is yellow"


def test_obj_texture_is_upright(ctx, tmp_path):
    texture = np.zeros((8, 8, 3), np.uint8)
    texture[:4] = [255, 0, 0]
    texture[4:] = [0, 0, 255]
    Image.fromarray(texture).save(tmp_path / "top_red.png")
    (tmp_path / "quad.mtl").write_text("newmtl painted\nKd 1 1 1\nmap_Kd top_red.png\n")
    (tmp_path / "quad.obj").write_text("mtllib quad.mtl\nv -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\n"
                                       "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl painted\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    renderer = TileRenderer(ctx, load_scene(str(tmp_path / "quad.obj")))
    pixels = renderer.render_frame(Camera(eye=(0.0, 0.0, 3.0), target=(0.0, 0.0, 0.0)), (40, 40)).pixels
    renderer.release()
    top, bottom = pixels[12, 20].astype(int), pixels[28, 20].astype(int)
    assert top[0] > 200 and top[2] < 50, f"top of the quad should be red, got {top}"
    assert bottom[2] > 200 and bottom[0] < 50, f"bottom of the quad should be blue, got {bottom}"


def run_render_once(tmp_path, name: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "node", "--render-once", str(tmp_path / name), *args], cwd=REPO,
                          capture_output=True, text=True, timeout=seconds(120))


def test_render_once_cli_is_deterministic_and_matches_the_renderer(tmp_path, renderers):
    bunny = str(scene_path("bunny/bun_zipper.ply"))
    camera = {"eye": [0.05, 0.16, 0.3], "target": [-0.02, 0.11, 0.0], "fovy_deg": 40}
    (tmp_path / "camera.json").write_text(json.dumps(camera))
    args = ("--scene", bunny, "--camera", str(tmp_path / "camera.json"), "--size", "160x120",
            "--background", "#1c1f26", "--interactive")
    images = []
    for name in ("a.png", "b.png"):
        result = run_render_once(tmp_path, name, *args)
        assert result.returncode == 0, result.stderr
        images.append(np.asarray(Image.open(io.BytesIO((tmp_path / name).read_bytes())).convert("RGB")))
    assert np.array_equal(images[0], images[1])
    assert np.array_equal(images[0][0, 0], [0x1C, 0x1F, 0x26])
    reference = renderers(bunny).render_frame(Camera.from_json(camera), (160, 120)).pixels
    assert np.array_equal(images[0], reference)


@pytest.mark.parametrize(("args", "needle"), [
    (("--scene", "builtin:spheres", "--camera", "CAMERA"), "coincide"),
    (("--scene", "/nonexistent/scene.glb"), "no such file"),
])
def test_render_once_cli_reports_one_error_line(tmp_path, args, needle):
    (tmp_path / "camera.json").write_text(json.dumps({"eye": [1, 1, 1], "target": [1, 1, 1]}))
    args = tuple(str(tmp_path / "camera.json") if a == "CAMERA" else a for a in args)
    result = run_render_once(tmp_path, "out.png", *args, "--size", "32x24")
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0]
    assert not (tmp_path / "out.png").exists()
