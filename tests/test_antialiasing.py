"""The one-sample frames' resolve filter (issue 20, :mod:`tessera.antialiasing`): the kernel, the
guard band, tiles that join into the filtered frame bit for bit on real GL, and what ``--msaa``
values turn it on."""

from __future__ import annotations

import numpy as np
import pytest

from bench.images import psnr
from bench.picture import supersampled
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.loading import load_scene
from tessera.antialiasing import guarded, resolve_filter
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


def test_tiles_filtered_with_their_guard_band_are_the_filtered_frame() -> None:
    frame = np.random.default_rng(3).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    whole = resolve_filter(frame, Rect(0, 0, 50, 40), Rect(0, 0, 50, 40))
    for rect in (Rect(0, 0, 17, 9), Rect(17, 9, 33, 31), Rect(49, 0, 1, 40)):
        drawn = guarded(rect, (50, 40))
        tile = resolve_filter(frame[drawn.y:drawn.y1, drawn.x:drawn.x1], rect, drawn)
        assert np.array_equal(tile, whole[rect.y:rect.y1, rect.x:rect.x1]), rect


@pytest.mark.gl
def test_filtered_tiles_join_seamlessly_and_come_closer_to_the_supersampled_frame(ctx) -> None:
    """``--msaa auto`` on llvmpipe: one sample and the filter, tiles equal to the whole frame; depth
    layers and ``--msaa 1`` are not filtered; the filter brings the frame closer to the 4×4
    supersampled one."""
    scene = load_scene(str(scene_path("bunny/bun_zipper.ply")))
    auto, plain = (TileRenderer(ctx, scene, shading=ShadingOptions(msaa=msaa)) for msaa in (0, 1))
    try:
        assert auto.filtered and auto.samples == 1 and not plain.filtered
        whole = auto.render_frame(CAMERA, SIZE).pixels
        for rect in RECTS:
            tile = auto.render_tile(CAMERA, SIZE, rect)
            assert tile.rect == rect and np.array_equal(tile.pixels, whole[rect.y:rect.y1, rect.x:rect.x1]), rect
        one_sample = plain.render_frame(CAMERA, SIZE).pixels
        assert np.array_equal(auto.render_layer(CAMERA, SIZE, Rect(0, 0, *SIZE)).pixels, one_sample)
        reference = supersampled(auto, CAMERA, SIZE)
        assert np.array_equal(reference, supersampled(plain, CAMERA, SIZE)), "the reference is never filtered"
        assert psnr(whole, reference) > psnr(one_sample, reference) + 2.0
    finally:
        auto.release()
        plain.release()
