"""The resolve filters of frames drawn with one sample, the pair or a grid of samples per pixel
(issues 20, 37, :mod:`tessera.antialiasing`): the kernels, the guard band, tiles that join into
the resolved frame bit for bit on real GL at each frame size's grid, and what ``--msaa`` values
turn them on."""

from __future__ import annotations

import numpy as np
import pytest

from bench.images import psnr
from bench.picture import supersampled
from node.gl.renderer import TileRenderer
from node.gl.shading import AUTO_MSAA, FILTER_MSAA, ShadingOptions
from node.scene.loading import load_scene
from tessera.antialiasing import guarded, resolve_filter, resolve_grid, resolve_pair_filter
from tessera.geometry import Camera, Rect
from tests.conftest import scene_path

SIZE = (160, 120)
CAMERA = Camera.from_json({"eye": [0.05, 0.16, 0.3], "target": [-0.02, 0.11, 0.0], "fovy_deg": 40})
RECTS = [Rect(0, 0, 97, 61), Rect(97, 0, 63, 61), Rect(0, 61, 1, 59), Rect(1, 61, 159, 59)]


def test_the_guard_band_is_one_pixel_clipped_to_the_frame() -> None:
    assert guarded(Rect(10, 20, 30, 40), (100, 100)) == Rect(9, 19, 32, 42)
    assert guarded(Rect(0, 0, 100, 100), (100, 100)) == Rect(0, 0, 100, 100)
    assert guarded(Rect(0, 50, 100, 50), (100, 100)) == Rect(0, 49, 100, 51)


def test_the_kernel_rounds_exactly_and_keeps_flat_areas() -> None:
    flat = np.full((5, 7, 3), 201, np.uint8)
    assert np.array_equal(resolve_filter(flat, Rect(0, 0, 7, 5), Rect(0, 0, 7, 5)), flat)
    dot = np.zeros((5, 5, 3), np.uint8)
    dot[2, 2] = 64
    out = resolve_filter(dot, Rect(1, 1, 3, 3), Rect(0, 0, 5, 5))[..., 0]
    assert out.tolist() == [[1, 6, 1], [6, 36, 6], [1, 6, 1]]   # [1, 6, 1] / 8 along x and y
    edge = np.zeros((1, 3, 3), np.uint8)
    edge[0, 0] = 8   # one row: the rows above and below are the frame's edge, clamped
    assert resolve_filter(edge, Rect(0, 0, 3, 1), Rect(0, 0, 3, 1))[0, :, 0].tolist() == [7, 1, 0]
    with pytest.raises(ValueError, match="guard band"):
        resolve_filter(flat, Rect(2, 0, 5, 5), Rect(0, 0, 7, 5))


def test_the_pair_kernel_sums_each_pixels_two_samples_then_filters_exactly() -> None:
    """Columns 2i and 2i + 1 are pixel i's samples: summed, then [1, 14, 1] / 16 along x and
    [1, 6, 1] / 8 along y, rounded half up; the largest sums fit 16 bits."""
    white = np.full((4, 10, 3), 255, np.uint8)
    assert np.array_equal(resolve_pair_filter(white, Rect(0, 0, 5, 4), Rect(0, 0, 5, 4)), white[:, :5])
    dot = np.zeros((5, 10, 3), np.uint8)
    dot[2, 4] = 255   # the left sample of pixel 2
    dot[2, 5] = 1     # and its right one: the pair sums to 256
    out = resolve_pair_filter(dot, Rect(1, 1, 3, 3), Rect(0, 0, 5, 5))[..., 0]
    assert out.tolist() == [[1, 14, 1], [6, 84, 6], [1, 14, 1]]   # 256 × (1, 14, 1) along x × (1, 6, 1) along y / 256
    half = np.zeros((1, 2, 3), np.uint8)
    half[0, 0] = 1   # a pair summing to 1 is half a level: rounded half up
    assert resolve_pair_filter(half, Rect(0, 0, 1, 1), Rect(0, 0, 1, 1))[0, 0, 0] == 1
    with pytest.raises(ValueError, match="twice as wide"):
        resolve_pair_filter(white[:, :9], Rect(0, 0, 5, 4), Rect(0, 0, 5, 4))


def test_a_grid_is_averaged_exactly_and_the_2x2_grid_filtered() -> None:
    """Each pixel's kx × ky block is its samples: 3×3 and 4×4 averaged, rounded half up; 2×2
    summed, then [1, 14, 1] / 16 along x and y (the sums fit 32 bits)."""
    rng = np.random.default_rng(4)
    for grid in ((3, 3), (4, 4)):
        kx, ky = grid
        samples = rng.integers(0, 256, (5 * ky, 6 * kx, 3), dtype=np.uint8)
        mean = samples.reshape(5, ky, 6, kx, 3).astype(np.float64).mean(axis=(1, 3))
        out = resolve_grid(samples, Rect(0, 0, 6, 5), Rect(0, 0, 6, 5), grid)
        assert np.array_equal(out, np.floor(mean + 0.5).astype(np.uint8)), grid
    with pytest.raises(ValueError, match="must be its rect"):
        resolve_grid(np.zeros((9, 9, 3), np.uint8), Rect(1, 1, 1, 1), Rect(0, 0, 3, 3), (3, 3))
    white = np.full((8, 10, 3), 255, np.uint8)
    assert np.array_equal(resolve_grid(white, Rect(0, 0, 5, 4), Rect(0, 0, 5, 4), (2, 2)), white[:4, :5])
    dot = np.zeros((10, 10, 3), np.uint8)
    dot[4:6, 4:6] = 64   # pixel (2, 2)'s four samples: 256
    out = resolve_grid(dot, Rect(1, 1, 3, 3), Rect(0, 0, 5, 5), (2, 2))[..., 0]
    assert out.tolist() == [[0, 4, 0], [4, 49, 4], [0, 4, 0]]   # 256 × (1, 14, 1)² / 1024, rounded half up


@pytest.mark.parametrize("resolve, width", [(resolve_filter, 1), (resolve_pair_filter, 2)])
def test_tiles_filtered_with_their_guard_band_are_the_filtered_frame(resolve, width) -> None:
    frame = np.random.default_rng(3).integers(0, 256, (40, 50 * width, 3), dtype=np.uint8)
    whole = resolve(frame, Rect(0, 0, 50, 40), Rect(0, 0, 50, 40))
    for rect in (Rect(0, 0, 17, 9), Rect(17, 9, 33, 31), Rect(49, 0, 1, 40)):
        drawn = guarded(rect, (50, 40))
        tile = resolve(frame[drawn.y:drawn.y1, width * drawn.x:width * drawn.x1], rect, drawn)
        assert np.array_equal(tile, whole[rect.y:rect.y1, rect.x:rect.x1]), rect


@pytest.mark.gl
@pytest.mark.parametrize("size, grid", [((160, 120), (4, 4)), ((500, 300), (3, 3)), ((800, 600), (2, 2))])
def test_grid_tiles_join_into_the_whole_frame_at_each_sizes_grid(ctx, size, grid) -> None:
    """``--msaa auto`` on llvmpipe draws more samples where a frame is small: each size's grid, and
    tiles of it equal their whole frame bit for bit (the 2×2 grid filtered with its guard band)."""
    scene = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    renderer = TileRenderer(ctx, scene)
    try:
        assert renderer.antialiasing.for_size(size).grid == grid
        whole = renderer.render_frame(CAMERA, size).pixels
        width, height = size
        third, half = width // 3, height // 2
        for rect in (Rect(0, 0, third, half), Rect(third, 0, width - third, half), Rect(0, half, 1, height - half),
                     Rect(1, half, width - 1, height - half)):
            tile = renderer.render_tile(CAMERA, size, rect)
            assert np.array_equal(tile.pixels, whole[rect.y:rect.y1, rect.x:rect.x1]), rect
        reference = supersampled(renderer, CAMERA, size)
        pair = TileRenderer(ctx, scene, shading=ShadingOptions(msaa=2))
        try:
            assert psnr(whole, reference) > psnr(pair.render_frame(CAMERA, size).pixels, reference) + 1.0
        finally:
            pair.release()
    finally:
        renderer.release()


@pytest.mark.gl
def test_filtered_tiles_join_seamlessly_and_come_closer_to_the_supersampled_frame(ctx) -> None:
    """On llvmpipe ``--msaa auto`` at 1280x720 draws two samples a pixel (twice as wide) and filters
    them, ``--msaa filter`` one sample; tiles of either equal their whole frame; depth layers and
    ``--msaa 1`` are neither; each step brings the frame closer to the 4×4 supersampled one."""
    scene = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    auto, filtered, plain = (TileRenderer(ctx, scene, shading=ShadingOptions(msaa=msaa))
                             for msaa in (AUTO_MSAA, FILTER_MSAA, 1))
    size = (1280, 720)
    rects = [Rect(0, 0, 700, 300), Rect(700, 0, 580, 300), Rect(0, 300, 1, 420), Rect(1, 300, 1279, 420)]
    try:
        drawn = {name: r.antialiasing.for_size(size) for name, r in (("auto", auto), ("filter", filtered),
                                                                      ("plain", plain))}
        assert (drawn["auto"].paired, drawn["auto"].filtered, drawn["auto"].samples) == (True, True, 1)
        assert (drawn["filter"].paired, drawn["filter"].filtered, drawn["plain"].resolved) == (False, True, False)
        frames = {}
        for name, renderer in (("auto", auto), ("filter", filtered)):
            frames[name] = whole = renderer.render_frame(CAMERA, size).pixels
            for rect in rects:
                tile = renderer.render_tile(CAMERA, size, rect)
                assert tile.rect == rect and np.array_equal(tile.pixels, whole[rect.y:rect.y1, rect.x:rect.x1]), \
                    (name, rect)
        one_sample = plain.render_frame(CAMERA, size).pixels
        assert np.array_equal(auto.render_layer(CAMERA, size, Rect(0, 0, *size)).pixels, one_sample)
        reference = supersampled(auto, CAMERA, size)
        assert np.array_equal(reference, supersampled(plain, CAMERA, size)), "the reference is never filtered"
        assert psnr(frames["auto"], reference) > psnr(frames["filter"], reference) + 0.5
        assert psnr(frames["filter"], reference) > psnr(one_sample, reference) + 2.0
    finally:
        for renderer in (auto, filtered, plain):
            renderer.release()
