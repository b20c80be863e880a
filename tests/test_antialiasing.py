"""The resolve filters of one-sample and paired frames (issue 20, :mod:`tessera.antialiasing`): the
kernels, the guard band, tiles that join into the filtered frame bit for bit on real GL, and what
``--msaa`` values turn them on."""

from __future__ import annotations

import numpy as np
import pytest

from bench.images import psnr
from bench.picture import supersampled
from node.gl.renderer import TileRenderer
from node.gl.shading import AUTO_MSAA, FILTER_MSAA, ShadingOptions
from node.scene.loading import load_scene
from tessera.antialiasing import guarded, resolve_filter, resolve_pair_filter
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


@pytest.mark.parametrize("resolve, width", [(resolve_filter, 1), (resolve_pair_filter, 2)])
def test_tiles_filtered_with_their_guard_band_are_the_filtered_frame(resolve, width) -> None:
    frame = np.random.default_rng(3).integers(0, 256, (40, 50 * width, 3), dtype=np.uint8)
    whole = resolve(frame, Rect(0, 0, 50, 40), Rect(0, 0, 50, 40))
    for rect in (Rect(0, 0, 17, 9), Rect(17, 9, 33, 31), Rect(49, 0, 1, 40)):
        drawn = guarded(rect, (50, 40))
        tile = resolve(frame[drawn.y:drawn.y1, width * drawn.x:width * drawn.x1], rect, drawn)
        assert np.array_equal(tile, whole[rect.y:rect.y1, rect.x:rect.x1]), rect


@pytest.mark.gl
def test_filtered_tiles_join_seamlessly_and_come_closer_to_the_supersampled_frame(ctx) -> None:
    """On llvmpipe ``--msaa auto`` draws two samples a pixel (twice as wide) and filters them,
    ``--msaa filter`` one sample; tiles of either equal their whole frame; depth layers and
    ``--msaa 1`` are neither; each step brings the frame closer to the 4×4 supersampled one."""
    scene = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    auto, filtered, plain = (TileRenderer(ctx, scene, shading=ShadingOptions(msaa=msaa))
                             for msaa in (AUTO_MSAA, FILTER_MSAA, 1))
    try:
        assert (auto.paired, auto.filtered, auto.samples) == (True, True, 1)
        assert (filtered.paired, filtered.filtered, plain.paired, plain.filtered) == (False, True, False, False)
        frames = {}
        for name, renderer in (("auto", auto), ("filter", filtered)):
            frames[name] = whole = renderer.render_frame(CAMERA, SIZE).pixels
            for rect in RECTS:
                tile = renderer.render_tile(CAMERA, SIZE, rect)
                assert tile.rect == rect and np.array_equal(tile.pixels, whole[rect.y:rect.y1, rect.x:rect.x1]), \
                    (name, rect)
        one_sample = plain.render_frame(CAMERA, SIZE).pixels
        assert np.array_equal(auto.render_layer(CAMERA, SIZE, Rect(0, 0, *SIZE)).pixels, one_sample)
        reference = supersampled(auto, CAMERA, SIZE)
        assert np.array_equal(reference, supersampled(plain, CAMERA, SIZE)), "the reference is never filtered"
        assert psnr(frames["auto"], reference) > psnr(frames["filter"], reference) + 0.5
        assert psnr(frames["filter"], reference) > psnr(one_sample, reference) + 2.0
    finally:
        for renderer in (auto, filtered, plain):
            renderer.release()
