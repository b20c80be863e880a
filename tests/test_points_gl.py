"""Point clouds drawn (issue 36): tiles equal the whole frame bit for bit (the budget's choice shared
by every tile, EDL with its guard band), two points 1 mm apart in UTM coordinates are two, the
budget bounds the points drawn and the still draws them down to its spacing on screen."""

from __future__ import annotations

import moderngl
import numpy as np
import pytest

from node.gl import point_renderer
from node.gl.point_renderer import PointRenderer
from node.scene.point_files import PointArrays
from node.scene.points import build_octree
from tessera.geometry import Camera, Rect, default_camera
from tessera.points.budget import STILL_EVERY_POINT_MAX

pytestmark = pytest.mark.gl

UTM = np.array([500000.0, 4000000.0, 100.0])


def terrain(count: int, seed: int = 3) -> PointArrays:
    """A rolling terrain of ``count`` points in survey coordinates, 200 m a side, coloured by height."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.0, 200.0, count), rng.uniform(0.0, 200.0, count)
    z = 8.0 * np.sin(x / 23.0) * np.cos(y / 31.0) + rng.normal(0.0, 0.02, count)
    return PointArrays(np.stack([x, y, z], axis=1) + UTM)


@pytest.fixture(scope="module")
def cloud_renderer(ctx: moderngl.Context) -> PointRenderer:
    cloud = build_octree(terrain(300_000), "terrain.laz", lambda fraction, message: None)
    renderer = PointRenderer(ctx, cloud)
    yield renderer
    renderer.release()


def oblique(bounds: np.ndarray) -> Camera:
    lo, hi = bounds
    centre = (lo + hi) / 2.0
    eye = centre + np.array([-60.0, -140.0, 90.0])
    return Camera(tuple(eye), tuple(centre), (0.0, 0.0, 1.0), 50.0)


@pytest.mark.parametrize("budget", [None, 40_000])
def test_tiles_equal_the_whole_frame(cloud_renderer: PointRenderer, budget: int | None) -> None:
    size = (160, 96)
    camera = oblique(cloud_renderer.scene.bounds)
    whole = cloud_renderer.render_frame(camera, size, point_budget=budget)
    assert (whole.pixels != whole.pixels[0, 0]).any()
    tiles = [Rect(0, 0, 53, 40), Rect(53, 0, 107, 40), Rect(0, 40, 90, 56), Rect(90, 40, 70, 56)]
    for rect in tiles:
        tile = cloud_renderer.render_tile(camera, size, rect, point_budget=budget)
        np.testing.assert_array_equal(tile.pixels, whole.pixels[rect.y:rect.y1, rect.x:rect.x1])
        assert tile.points <= whole.points


def test_the_budget_bounds_the_points_drawn(cloud_renderer: PointRenderer, monkeypatch: pytest.MonkeyPatch) -> None:
    """Within a budget, at most that many points; a still of a cloud whose points in view are fewer
    than :data:`STILL_EVERY_POINT_MAX`, every point in view (the whole terrain); above it, at the
    default spacing, fewer in a frame smaller than the cloud's points; at a spacing of 0 (the
    coordinator's still of every point), every point in view again, the picture of every point."""
    size = (160, 96)
    camera = oblique(cloud_renderer.scene.bounds)
    everything = cloud_renderer.render_frame(camera, size)
    budgeted = cloud_renderer.render_frame(camera, size, point_budget=50_000)
    monkeypatch.setattr(cloud_renderer, "still_every_point_max", 0)
    spaced = cloud_renderer.render_frame(camera, size)
    assert budgeted.points <= 50_000 < spaced.points < everything.points < STILL_EVERY_POINT_MAX
    assert everything.points == cloud_renderer.scene.point_count
    cloud_renderer.style(None, 0.0)
    try:
        every = cloud_renderer.render_frame(camera, size)
    finally:
        cloud_renderer.style()
    assert every.points == everything.points and np.array_equal(every.pixels, everything.pixels)
    assert not np.array_equal(spaced.pixels, everything.pixels)
    assert spaced.left_out == everything.points - spaced.points and every.left_out == everything.left_out == 0
    assert budgeted.left_out == 0 and spaced.stats()["points_left_out"] == spaced.left_out


def test_points_a_millimetre_apart_in_utm_coordinates_stay_apart(ctx: moderngl.Context) -> None:
    """A 9 x 9 grid of points 1 mm apart at UTM (500000, 4000000, 100), every other column white,
    seen from 1 cm: each white column is a run of its own, 2 mm (tens of pixels) from the next. In
    float32 world coordinates (31 mm apart there) they would fall onto one point."""
    x, y = np.meshgrid(np.arange(9) * 0.001, np.arange(9) * 0.001)
    positions = np.stack([x.ravel(), y.ravel(), np.zeros(81)], axis=1) + UTM
    colors = np.where((np.arange(81) % 9 % 2 == 0)[:, None], 255, 0).astype(np.uint8).repeat(3, axis=1)
    renderer = PointRenderer(ctx, build_octree(PointArrays(positions, colors), "grid.las", lambda f, m: None),
                             point_size=1.0)
    try:
        target = UTM + np.array([0.004, 0.004, 0.0])
        camera = Camera(tuple(target + np.array([0.0, 0.0, 0.01])), tuple(target), (0.0, 1.0, 0.0), 30.0)
        pixels = renderer.render_frame(camera, (200, 120)).pixels
        row = pixels[60, :, 0] > 128
        starts = np.flatnonzero(row[1:] & ~row[:-1]) + 1
        assert len(starts) >= 3, f"white columns expected apart, bright pixels at {np.flatnonzero(row)}"
        pitch = np.diff(starts)
        assert (np.abs(pitch - pitch.mean()) <= 2).all() and 30 < pitch.mean() < 60   # 2 mm at 1 cm: ~45 px
    finally:
        renderer.release()


def test_the_still_draws_every_point_and_is_steady(cloud_renderer: PointRenderer) -> None:
    size = (96, 64)
    camera = default_camera(cloud_renderer.scene.bounds, aspect=1.5)
    first = cloud_renderer.render_still(camera, size, 3)
    again = cloud_renderer.render_still(camera, size, 3)
    np.testing.assert_array_equal(first, again)


def test_a_draw_in_pieces_equals_one_draw_and_stops_between_pieces(cloud_renderer: PointRenderer,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """A still's tile drawn in pieces (so that a cancel can stop it) is the tile drawn at once, bit
    for bit; ``stop`` is asked between two pieces, and once it says so the draw is given up."""
    monkeypatch.setattr(point_renderer, "PIECE_POINTS", 20_000)
    size, rect = (160, 96), Rect(40, 10, 90, 70)
    camera = oblique(cloud_renderer.scene.bounds)
    at_once = cloud_renderer.render_tile(camera, size, rect)
    asked: list[int] = []
    pieces = cloud_renderer.render_tile(camera, size, rect, stop=lambda: bool(asked.append(1)))
    np.testing.assert_array_equal(pieces.pixels, at_once.pixels)
    assert pieces.points == at_once.points > 100_000
    assert len(asked) >= at_once.points // 20_000 - 1, "stop is asked between every two pieces"
    with pytest.raises(point_renderer.DrawStopped):
        cloud_renderer.render_tile(camera, size, rect, stop=lambda: True)


def test_pieces_cover_the_commands_in_order_without_cutting_one() -> None:
    counts = np.array([60_000, 60_000, 10, 140_000, 5, 5, 99_990, 1])
    starts = point_renderer.draw_pieces(counts)
    assert starts[0] == 0 and starts[-1] == len(counts) and (np.diff(starts) > 0).all()
    first_points = (np.cumsum(counts) - counts)[starts[:-1]]
    assert (np.diff(first_points // point_renderer.PIECE_POINTS) > 0).all(), "each piece in a block of its own"
    assert point_renderer.draw_pieces(np.array([5])).tolist() == [0, 1]


def test_a_cloud_uploaded_in_steps_draws_the_nodes_it_holds_then_as_if_uploaded_at_once(
        ctx: moderngl.Context, cloud_renderer: PointRenderer) -> None:
    """Given its first 20 000 points (the coarse levels), a renderer draws a budget's frame from the
    nodes wholly among them; once the rest came in steps, the frame uploaded at once, bit for bit."""
    cloud, size = cloud_renderer.scene, (160, 96)
    camera = oblique(cloud.bounds)
    partial = PointRenderer(ctx, cloud, first_points=20_000)
    try:
        assert not partial.complete and partial.uploaded == 20_000
        early = partial.render_frame(camera, size, point_budget=40_000)
        chosen = partial.choose(camera, size, 40_000)
        assert chosen.any() and (cloud.nodes.first[1:][chosen] <= 20_000).all()
        assert 0 < early.points <= 20_000
        steps = 1
        while not partial.upload_step(50_000):
            steps += 1
        assert steps == -(-(cloud.point_count - 20_000) // 50_000) and partial.uploaded == cloud.point_count
        np.testing.assert_array_equal(partial.render_frame(camera, size, point_budget=40_000).pixels,
                                      cloud_renderer.render_frame(camera, size, point_budget=40_000).pixels)
    finally:
        partial.release()


def test_a_still_sample_uploads_every_point_first_and_stops_between_steps(
        ctx: moderngl.Context, cloud_renderer: PointRenderer, monkeypatch: pytest.MonkeyPatch) -> None:
    """A still's tile (no budget) of a cloud not all uploaded copies the rest first, a step at a
    time, and is given up between two steps once ``stop`` says so; drawn, it is the tile of the
    cloud uploaded at once."""
    monkeypatch.setattr(point_renderer, "UPLOAD_STEP_POINTS", 30_000)
    cloud, size, rect = cloud_renderer.scene, (160, 96), Rect(40, 10, 90, 70)
    camera = oblique(cloud.bounds)
    partial = PointRenderer(ctx, cloud, first_points=10_000)
    try:
        with pytest.raises(point_renderer.DrawStopped):
            partial.render_tile(camera, size, rect, stop=lambda: True)
        assert partial.uploaded == 40_000, "one step, then stopped"
        tile = partial.render_tile(camera, size, rect)
        assert partial.complete
        expected = cloud_renderer.render_tile(camera, size, rect)
        assert tile.points == expected.points
        np.testing.assert_array_equal(tile.pixels, expected.pixels)
    finally:
        partial.release()
