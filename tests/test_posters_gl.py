"""Pictures larger than a frame drawn by windows on real GL (llvmpipe, issue 35): a poster's pieces,
each drawn into its window's framebuffer, join into exactly what ``--render-once`` draws at that
size, whatever the pieces' size, and that picture has no seam where two windows meet."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from bench.images import psnr
from node.gl.renderer import TileRenderer
from node.render_once import draw_picture
from node.scene.builtin import build_builtin_scene
from tessera.geometry import Camera, Rect
from tessera.scheduling.refinement import StillPlan
from tessera.scheduling.render_jobs import pieces, windows

pytestmark = pytest.mark.gl

#: Wider than a window: two windows meet at x = 4096, across the spheres in the middle.
SIZE = (8000, 64)
CAMERA = Camera(eye=(0.1, 0.5, 4.5), target=(0.1, 0.45, 0.0), fovy_deg=2.0)


@pytest.fixture(scope="module")
def renderer(ctx):
    made = TileRenderer(ctx, build_builtin_scene("spheres"))
    yield made
    made.release()


def assembled(renderer: TileRenderer, side: int, subsample) -> np.ndarray:
    picture = np.zeros((SIZE[1], SIZE[0], 3), np.uint8)
    for rect, window in pieces(SIZE, side):
        tile = renderer.render_tile(CAMERA, SIZE, rect, subsample=subsample, window=window)
        assert tile.rect == rect
        picture[rect.y:rect.y1, rect.x:rect.x1] = tile.pixels
    return picture


@pytest.mark.parametrize("plan, sample", [(StillPlan(1), 0), (StillPlan(4), 3)])
def test_pieces_of_any_size_join_into_render_once_without_a_seam(renderer, plan: StillPlan, sample: int) -> None:
    assert len(windows(SIZE)) == 2
    subsample = plan.subsample(sample)
    reference = draw_picture(renderer, CAMERA, SIZE, None, subsample)
    for side in (90, 333, 1024):
        assert np.array_equal(assembled(renderer, side, subsample), reference), side
    whole = renderer.render_frame(CAMERA, SIZE, subsample=subsample).pixels   # one 8000-wide framebuffer
    assert psnr(reference, whole) >= 50.0
    seam = np.abs(reference[:, 4090:4102].astype(int) - whole[:, 4090:4102]).max()
    assert seam <= 2, f"the windows' join differs from the whole frame by {seam} levels"
    assert reference[:, 4080:4112].std() > 5.0, "the join crosses the scene"


@pytest.mark.parametrize("size", [(640, 360), (960, 540), (1280, 720)])
def test_a_stills_sample_in_tiles_equals_the_whole_sample_at_every_grid(renderer, size) -> None:
    """Every size's grid (3x3, 2x2, the pair): a still's samples are averaged, not filtered, so
    tiles cut at odd columns join into the whole sample (a poster's pieces rely on it)."""
    camera = Camera(eye=(0.1, 0.5, 4.5), target=(0.1, 0.45, 0.0), fovy_deg=30.0)
    subsample = StillPlan(4).subsample(3)
    whole = renderer.render_frame(camera, size, subsample=subsample).pixels
    cuts = [0, 89, 178, 301, 433, size[0]]
    tiles = [renderer.render_tile(camera, size, Rect(x0, 0, x1 - x0, size[1]), subsample=subsample).pixels
             for x0, x1 in itertools.pairwise(cuts)]
    joined = np.concatenate(tiles, axis=1)
    assert np.array_equal(joined, whole), renderer.antialiasing.for_size(size).grid
