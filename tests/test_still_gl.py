"""The progressive still on real GL (issues 20, 37): jittered tiles join into the jittered frame bit
for bit, the accumulated still is the mean of the jittered frames and comes closer to the 4×4
supersampled frame than one sample, the adaptive still stops at a check where its estimate reached
its target and that estimate does not overstate how near it is to the image its samples converge
to, and ``--render-once`` renders the adaptive still by default (``--samples N``, ``--interactive``)."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from PIL import Image

from bench.images import psnr
from bench.picture import supersampled
from node.gl.renderer import TileRenderer
from node.gl.shading import ShadingOptions
from node.scene.loading import load_scene
from tessera.geometry import Camera, Rect
from tessera.scheduling.refinement import (
    ADAPTIVE,
    DEFAULT_STILL_SAMPLES,
    StillPlan,
    Subsample,
    accumulate,
    accumulate_still,
    grid_subsample,
    subsample,
)
from tests.conftest import scene_path
from tests.test_render_gl import run_render_once

pytestmark = pytest.mark.gl

SIZE = (160, 120)
CAMERA = {"eye": [0.05, 0.16, 0.3], "target": [-0.02, 0.11, 0.0], "fovy_deg": 40}
RECTS = [Rect(0, 0, 97, 61), Rect(97, 0, 63, 61), Rect(0, 61, 160, 59)]


@pytest.fixture(scope="module")
def bunny(ctx):
    renderer = TileRenderer(ctx, load_scene(str(scene_path("bunny/bun_zipper.ply"))))
    yield renderer
    renderer.release()


def test_jittered_tiles_join_into_the_jittered_frame(bunny) -> None:
    camera = Camera.from_json(CAMERA)
    sample = subsample(3, 8)
    whole = bunny.render_frame(camera, SIZE, subsample=sample).pixels
    assert not np.array_equal(whole, bunny.render_frame(camera, SIZE).pixels), "the jitter moves the picture"
    for rect in RECTS:
        tile = bunny.render_tile(camera, SIZE, rect, subsample=sample).pixels
        assert np.array_equal(tile, whole[rect.y:rect.y1, rect.x:rect.x1]), f"tile {rect} differs"


def test_the_still_is_the_mean_of_its_jittered_samples_and_nears_the_supersampled_frame(bunny) -> None:
    camera = Camera.from_json(CAMERA)
    samples = 8
    frames = [bunny.render_frame(camera, SIZE, subsample=subsample(k, samples)).pixels for k in range(samples)]
    still = bunny.render_still(camera, SIZE, samples)
    assert np.array_equal(still, accumulate(frames))
    assert np.array_equal(bunny.render_still(camera, SIZE, 1), bunny.render_frame(camera, SIZE).pixels)
    reference = supersampled(bunny, camera, SIZE)
    plain = TileRenderer(bunny.ctx, bunny.scene, shading=ShadingOptions(msaa=1))
    try:
        one = psnr(plain.render_frame(camera, SIZE).pixels, reference)
        singles = [plain.render_frame(camera, SIZE, subsample=subsample(k, samples)).pixels for k in range(samples)]
    finally:
        plain.release()
    assert psnr(still, reference) > one + 3.0, "accumulated samples come closer to the supersampled frame"
    assert psnr(still, reference) > psnr(accumulate(singles), reference) + 3.0, \
        "each sample of a small frame is its 4x4 grid, shifted within the cells: worth more than one sample"


def test_a_grid_sample_is_the_grid_shifted_within_its_cells() -> None:
    sample = Subsample((0.25, -0.125), -1.5)
    assert grid_subsample(sample, (1, 1)) is sample
    assert grid_subsample(sample, (2, 1)) == Subsample((0.125, -0.125), -1.5)
    assert grid_subsample(sample, (3, 3)) == Subsample((0.25 / 3, -0.125 / 3), -1.5 + np.log2(3))
    assert grid_subsample(Subsample(None, -2.0), (2, 2)) == Subsample(None, -1.0)


def test_the_adaptive_still_stops_where_its_estimate_reaches_the_target_and_does_not_overstate_it(bunny) -> None:
    camera = Camera.from_json(CAMERA)
    plan = StillPlan(ADAPTIVE, max_samples=64, target_db=44.0)

    def draw(sample):
        return bunny.render_frame(camera, SIZE, subsample=sample).pixels

    still = accumulate_still(draw, SIZE, plan)
    assert still.count in plan.checks() and still.count < plan.most and still.estimate_db >= plan.target_db
    longer = accumulate_still(draw, SIZE, StillPlan(ADAPTIVE, max_samples=64, target_db=99.0))
    assert longer.count == 64
    assert psnr(still.mean(), longer.mean()) >= still.estimate_db - 0.5, "the estimate does not overstate"
    assert np.array_equal(bunny.render_still(camera, SIZE, plan), still.mean())


def test_render_once_renders_the_still_by_default(tmp_path, bunny) -> None:
    (tmp_path / "camera.json").write_text(json.dumps(CAMERA))
    args = ("--scene", str(scene_path("bunny/bun_zipper.ply")), "--camera", str(tmp_path / "camera.json"),
            "--size", f"{SIZE[0]}x{SIZE[1]}")
    camera = Camera.from_json(CAMERA)
    expected = {"still.png": bunny.render_still(camera, SIZE, DEFAULT_STILL_SAMPLES),
                "two.png": bunny.render_still(camera, SIZE, 2),
                "interactive.png": bunny.render_frame(camera, SIZE).pixels}
    for name, extra in (("still.png", ()), ("two.png", ("--samples", "2")), ("interactive.png", ("--interactive",))):
        result = run_render_once(tmp_path, name, *args, *extra)
        assert result.returncode == 0, result.stderr
        assert name != "still.png" or "estimated" in result.stdout, result.stdout
        image = np.asarray(Image.open(io.BytesIO((tmp_path / name).read_bytes())).convert("RGB"))
        assert np.array_equal(image, expected[name]), name
    result = run_render_once(tmp_path, "bad.png", *args, "--samples", "0")
    assert result.returncode != 0 and "samples" in result.stderr
