"""The glTF metallic-roughness shading, image-based lighting and MSAA on llvmpipe (issue 20), on
small frames: white furnace, roughness, normal maps, materials that matter, seamless MSAA tiles,
environment files."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from bench.picture import SPHERE_CAMERA, luma, material_contrast, sphere_scene
from node.gl.environment import EnvironmentError, read_hdr, studio_environment, write_hdr
from node.gl.image_lighting import LEVELS, brdf_lut, ggx_convolve, irradiance_polynomial, irradiance_sh, sh_basis
from node.gl.renderer import TileRenderer
from node.gl.shading import AUTO_MSAA, FILTER_MSAA, Antialiasing, ShadingOptions, resolve_antialiasing
from node.scene.data import SceneData
from node.scene.material import SurfaceMaterial
from node.scene.mesh import MeshBatch
from node.settings import parse_settings
from tessera.geometry import Camera, Rect
from tests.conftest import PYTHON, REPO, seconds

pytestmark = pytest.mark.gl

SIZE = (96, 96)


def neutral_tone_map(color: np.ndarray) -> np.ndarray:
    """Khronos PBR Neutral of linear (…, 3) colours (the reference for the shader's)."""
    start, desaturation = 0.76, 0.15
    x = color.min(axis=-1, keepdims=True)
    color = color - np.where(x < 0.08, x - 6.25 * x * x, 0.04)
    peak = color.max(axis=-1, keepdims=True)
    d = 1.0 - start
    new_peak = 1.0 - d * d / (peak + d - start)
    g = 1.0 - 1.0 / (desaturation * (peak - new_peak) + 1.0)
    compressed = color * new_peak / peak * (1.0 - g) + new_peak * g
    return np.where(peak < start, color, compressed)


def srgb_bytes(linear: np.ndarray) -> np.ndarray:
    encoded = np.where(linear <= 0.0031308, linear * 12.92, 1.055 * np.power(linear, 1.0 / 2.4) - 0.055)
    return np.rint(np.clip(encoded, 0.0, 1.0) * 255.0)


def uniform_environment(tmp_path, radiance: float):
    path = tmp_path / f"uniform-{radiance}.hdr"
    write_hdr(path, np.full((16, 32, 3), radiance, np.float32))
    return path


def render(ctx, scene: SceneData, shading: ShadingOptions, size=SIZE, camera: Camera = SPHERE_CAMERA) -> np.ndarray:
    renderer = TileRenderer(ctx, scene, (0.0, 0.0, 0.0), shading=shading)
    try:
        return renderer.render_frame(camera, size).pixels
    finally:
        renderer.release()


def test_a_rough_white_sphere_vanishes_into_a_uniform_white_environment(ctx, tmp_path):
    """White furnace: with no key light, a rough white dielectric (and a smooth white metal) in a
    uniform environment of radiance L reflects exactly L everywhere, rim included."""
    radiance = 0.5
    shading = ShadingOptions(msaa=1, environment=uniform_environment(tmp_path, radiance), key_light=0.0)
    expected = srgb_bytes(neutral_tone_map(np.full(3, radiance)))
    for material in (SurfaceMaterial(metallic=0.0, roughness=1.0), SurfaceMaterial(metallic=1.0, roughness=0.0),
                     SurfaceMaterial(metallic=0.0, roughness=0.5)):
        pixels = render(ctx, sphere_scene(material, (1.0, 1.0, 1.0)), shading)
        sphere = pixels[pixels.max(axis=2) > 0].astype(np.float64)
        assert len(sphere) > 0.2 * SIZE[0] * SIZE[1]
        assert np.abs(sphere - expected).max() <= 3.0, f"{material}: {sphere.min(axis=0)}..{sphere.max(axis=0)}"


def test_roughness_widens_the_highlight_monotonically(ctx, tmp_path):
    """A gold metal sphere: lit by the key light alone (a black environment), its highlight's area
    (pixels over half the peak luma) grows with roughness; in the studio, the luma spread over the
    sphere narrows as the environment's reflection blurs."""
    dark = ShadingOptions(msaa=1, environment=uniform_environment(tmp_path, 0.0))
    areas, spreads = [], []
    for roughness in (0.2, 0.4, 0.6, 0.8):
        material = SurfaceMaterial(metallic=1.0, roughness=roughness)
        values = luma(render(ctx, sphere_scene(material), dark))
        areas.append(int(np.sum(values > 0.5 * values.max())))
        pixels = render(ctx, sphere_scene(material), ShadingOptions(msaa=1, key_light=0.0))
        studio = luma(pixels[pixels.max(axis=2) > 0])
        spreads.append(float(np.percentile(studio, 99) - np.percentile(studio, 1)))
    assert areas == sorted(areas) and areas[-1] > 3 * areas[0], areas
    assert spreads == sorted(spreads, reverse=True) and spreads[0] > 1.2 * spreads[-1], spreads


def test_a_smooth_metal_and_a_rough_dielectric_of_one_colour_differ_clearly(ctx):
    """The issue's figure (was a spread ratio of 0.91 and 5 levels with Lambert shading)."""
    contrast = material_contrast(ctx, (128, 128))
    assert contrast["spread_ratio"] < 0.8 and contrast["colour_distance"] > 30.0, contrast


def textured_quad(normal_map: np.ndarray | None) -> SceneData:
    """A 2×2 quad in the z = 0 plane facing +z, uvs 0…1, grey, rough dielectric, ``normal_map``."""
    positions = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float32)
    normals = np.tile(np.array([0, 0, 1], np.float32), (4, 1))
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    batch = MeshBatch("quad", positions, normals, np.array([[0, 1, 2], [0, 2, 3]], np.uint32), uvs=uvs,
                      base_color=np.array([0.6, 0.6, 0.6, 1.0], np.float32),
                      material=SurfaceMaterial(metallic=0.0, roughness=0.5, normal_texture=normal_map))
    return SceneData.from_batches("quad", [batch])


def test_a_normal_map_changes_shading_and_a_flat_one_does_not(ctx):
    camera = Camera(eye=(0.0, 0.0, 2.2), target=(0.0, 0.0, 0.0), fovy_deg=50.0, near=0.1, far=10.0)
    shading = ShadingOptions(msaa=1)
    plain = render(ctx, textured_quad(None), shading, camera=camera)
    flat = np.zeros((16, 16, 4), np.uint8) + np.array([128, 128, 255, 255], np.uint8)
    stripes = np.linspace(-0.7, 0.7, 16)[None, :].repeat(16, axis=0)
    bumpy = np.stack([stripes * 127 + 128, np.full_like(stripes, 128),
                      np.sqrt(1 - stripes ** 2) * 127 + 128, np.full_like(stripes, 255)], axis=-1).astype(np.uint8)
    with_flat = render(ctx, textured_quad(flat), shading, camera=camera)
    with_bumps = render(ctx, textured_quad(bumpy), shading, camera=camera)
    assert np.abs(with_flat.astype(int) - plain).max() <= 2
    difference = np.abs(with_bumps.astype(int) - plain).max(axis=2)
    assert np.mean(difference > 10) > 0.15, "the normal map must change the shading of much of the quad"
    left, right = luma(with_bumps[48, 15:25]).mean(), luma(with_bumps[48, 70:80]).mean()
    assert abs(left - right) > 10, "normals tilted left and right must shade differently"


def test_emission_adds_its_colour(ctx):
    """Green emission brightens green; red moves only by the tone mapper's desaturation of bright values."""
    shading = ShadingOptions(msaa=1, key_light=0.0)
    base = render(ctx, sphere_scene(SurfaceMaterial(), (0.2, 0.2, 0.2)), shading)
    glowing = render(ctx, sphere_scene(SurfaceMaterial(emissive=(0.0, 0.5, 0.0)), (0.2, 0.2, 0.2)), shading)
    inside = base.max(axis=2) > 0
    assert (glowing[inside][:, 1].astype(int) - base[inside][:, 1]).min() > 20
    assert np.abs(glowing[inside][:, 0].astype(int) - base[inside][:, 0]).max() <= 6


@pytest.mark.parametrize("msaa", [1, 4])
def test_msaa_tiles_join_seamlessly(ctx, msaa):
    """Tiles of a multisampled frame, each resolved on its own, are the whole frame bit for bit;
    and 4 samples do smooth the sphere's silhouette."""
    scene = sphere_scene(SurfaceMaterial(metallic=1.0, roughness=0.3))
    renderer = TileRenderer(ctx, scene, (0.1, 0.1, 0.1), shading=ShadingOptions(msaa=msaa))
    try:
        size = (80, 60)
        whole = renderer.render_frame(SPHERE_CAMERA, size).pixels
        tiled = np.zeros_like(whole)
        for rect in (Rect(0, 0, 33, 27), Rect(33, 0, 47, 27), Rect(0, 27, 41, 33), Rect(41, 27, 39, 33)):
            tiled[rect.y:rect.y1, rect.x:rect.x1] = renderer.render_tile(SPHERE_CAMERA, size, rect).pixels
        assert np.array_equal(tiled, whole)
        one_sample = renderer.render_layer(SPHERE_CAMERA, size, Rect(0, 0, *size)).pixels
        changed = np.abs(whole.astype(int) - one_sample).max(axis=2) > 0
        if renderer.antialiasing.for_size(size).samples > 1:
            assert 0 < changed.mean() < 0.2, "depth layers are drawn at one sample; MSAA changes edge pixels only"
        else:
            assert not changed.any()
    finally:
        renderer.release()


def test_environment_files_round_trip_and_bad_ones_are_refused(tmp_path):
    studio = studio_environment(16)
    path = tmp_path / "studio.hdr"
    write_hdr(path, studio)
    again = read_hdr(path)
    assert again.shape == (16, 32, 3) and np.allclose(again, studio, rtol=0.01, atol=1e-3)
    # A run-length encoded file: two scanlines of 8 pixels, each channel one run.
    rle = tmp_path / "rle.hdr"
    scanline = bytes([2, 2, 0, 8]) + bytes([128 + 8, 128, 128 + 8, 64, 128 + 8, 0, 128 + 8, 129])
    rle.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 8\n" + scanline * 2)
    image = read_hdr(rle)
    assert image.shape == (2, 4, 3) and np.allclose(image, [1.0, 0.5, 0.0])
    bad = tmp_path / "bad.hdr"
    bad.write_bytes(b"P6\n1 1\n255\n\x00\x00\x00")
    with pytest.raises(EnvironmentError, match=r"bad\.hdr: not a Radiance"):
        read_hdr(bad)
    with pytest.raises(EnvironmentError, match="unreadable"):
        read_hdr(tmp_path / "missing.hdr")


def test_prefiltering_keeps_energy_and_the_brdf_table_is_bounded():
    """Convolving a uniform map keeps it uniform; SH of a uniform map is its value everywhere;
    A + B of the split sum never exceeds 1 and a smooth surface seen head-on reflects all of F0."""
    uniform = np.full((8, 16, 3), 0.7, np.float32)
    assert np.allclose(ggx_convolve(uniform, 4, 0.6), 0.7, atol=1e-4)
    sh = irradiance_sh(uniform)
    directions = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, -0.6, 0.8]])
    assert np.allclose(sh_basis(directions) @ sh, 0.7, atol=0.015)  # an 8x16 map's quadrature error
    studio = irradiance_sh(studio_environment(16))
    n = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    x, y, z = n.T
    monomials = np.stack([np.ones_like(x), y, z, x, x * y, y * z, z * z, x * z, x * x - y * y], axis=1)
    assert np.allclose(monomials @ irradiance_polynomial(studio), sh_basis(n) @ studio, atol=1e-5)
    lut = brdf_lut(16, 128)
    assert (lut.sum(axis=-1) <= 1.0 + 1e-3).all() and lut[0, -1, 0] > 0.95 and LEVELS >= 5


def test_node_flags_and_render_once_with_a_bad_environment(tmp_path):
    settings = parse_settings(["--msaa", "1", "--environment", "studio.hdr"], {})
    assert settings.shading == ShadingOptions(msaa=1, environment=settings.environment)
    assert parse_settings([], {"TESSERA_MSAA": "2"}).msaa == 2
    assert parse_settings([], {}).msaa == AUTO_MSAA == parse_settings(["--msaa", "auto"], {}).msaa
    assert parse_settings(["--msaa", "Filter"], {}).msaa == FILTER_MSAA
    llvmpipe, gpu = "llvmpipe (LLVM 15.0.6, 256 bits)", "NVIDIA H100 80GB HBM3/PCIe/SSE2"
    paired = Antialiasing(samples=1, grid=(2, 1), filtered=True)
    by_size = resolve_antialiasing(AUTO_MSAA, llvmpipe, 4)
    assert by_size.for_size((1280, 720)) == paired == resolve_antialiasing(2, llvmpipe, 4).for_size((640, 360))
    assert [by_size.for_size(size).grid for size in ((320, 180), (640, 360), (960, 540), (1280, 720), (1920, 1080))] \
        == [(4, 4), (3, 3), (2, 2), (2, 1), (2, 1)], "more samples where a frame is small, the pair from 720p"
    assert by_size.for_size((960, 540)).filtered and not by_size.for_size((640, 360)).filtered
    assert resolve_antialiasing(AUTO_MSAA, gpu, 32).for_size((320, 180)) == Antialiasing(samples=4)
    assert resolve_antialiasing(2, gpu, 32).fixed == Antialiasing(samples=2)
    assert resolve_antialiasing(8, llvmpipe, 4).fixed == Antialiasing(samples=4)
    assert resolve_antialiasing(FILTER_MSAA, gpu, 32).fixed == Antialiasing(filtered=True)
    assert resolve_antialiasing(1, llvmpipe, 4).fixed == Antialiasing()
    with pytest.raises(SystemExit):
        parse_settings(["--msaa", "3"], {})
    bad = tmp_path / "bad.hdr"
    bad.write_text("not an image")
    result = subprocess.run([PYTHON, "-m", "node", "--render-once", str(tmp_path / "out.png"), "--scene",
                             "builtin:spheres", "--size", "32x24", "--environment", str(bad)],
                            cwd=REPO, capture_output=True, text=True, timeout=seconds(120))
    assert result.returncode == 1 and "bad.hdr: not a Radiance" in result.stderr
    assert not (tmp_path / "out.png").exists()


def test_a_scan_without_material_is_a_matte_dielectric_and_gltf_defaults_follow_the_spec():
    from node.scene.loading import load_scene
    from tests.conftest import scene_path

    bunny = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    assert all(b.material.metallic == 0.0 and 0.3 <= b.material.roughness <= 0.8 for b in bunny.batches)
    truck = load_scene(str(scene_path("gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf")))
    # The truck's materials set metallicFactor 0 and leave roughness out (spec default 1).
    assert all(b.material.metallic == 0.0 and b.material.roughness == 1.0 for b in truck.batches)


def test_what_trimesh_drops_of_a_gltf_material_is_read_from_its_json():
    from node.scene.material import MaterialExtras, material_extras

    gltf = {"materials": [
        {"name": "lamp", "normalTexture": {"index": 0, "scale": 0.5},
         "occlusionTexture": {"index": 1, "strength": 0.25},
         "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 6.0}}},
        {"name": "plain"}, {"normalTexture": {"scale": 2.0}},
        {"name": "odd", "normalTexture": {"scale": "big"}, "occlusionTexture": {"strength": -1}}]}
    assert material_extras(gltf) == {"lamp": MaterialExtras(0.5, 0.25, 6.0), "plain": MaterialExtras(),
                                     "odd": MaterialExtras()}
