"""Levels of detail (issue 32, node/scene/lod.py, node/culling/lod.py, node/gl/lod_draws.py): the
cluster DAG's errors grow from 0 at full detail to the top and its boxes hold their inputs', each
level at most halves the one below down to a few clusters, a cluster's triangles stay within its box
and its group's, the levels cost at most 40 % more memory; a frame's choice is a function of the
camera alone, closed under the groups' inputs and covers the model exactly once (a flat square's
area exactly); tiles at mixed levels join as the whole frame bit for bit; a rippled sheet cut at two
levels shows no crack; the moving frame keeps to 38 dB against full detail on the real scans; the
balancers' predictions follow the triangles the levels draw."""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from node.culling.lod import LodCut, back_faces_hidden, lod_cut, projected_errors, subtract_ranges
from node.culling.switch import CullMode, SwitchParams
from node.gl.renderer import TileRenderer, backless_batches
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.lod import PART_FACES, LodTree, _weld, build_lod, closed_surface, group_levels
from node.scene.mesh import MeshBatch
from tessera.balancers.projection import level_counts
from tessera.geometry import Camera, Rect, default_camera, view_projection
from tessera.scheduling.lod_control import DEFAULT_LOD_ERROR_PX
from tests.conftest import scene_path
from tests.culling_support import random_cameras

LUCY = "large_scan/stanford_lucy_240k.ply"
PAN = "large_scan/threedscans_pan_990k.ply"
DRAGON = "large_scan/stanford_dragon_vrip_res2_202k.ply"


@pytest.fixture(scope="module")
def dragon() -> tuple[SceneData, LodTree]:
    scene = load_scene(str(scene_path(DRAGON)))
    return scene, build_lod(scene, lambda fraction, message: None)


def test_errors_grow_from_full_detail_to_the_top(dragon):
    scene, tree = dragon
    assert tree.node_count > 20 and tree.group_level.max() >= 3
    assert np.all(tree.group_error > 0.0)
    has_parent = tree.parent >= 0
    parent, own = tree.parent[has_parent], tree.own[has_parent]
    assert np.all(tree.group_error[parent] >= tree.group_error[own]), "a group's error covers its inputs'"
    assert np.all(tree.group_level[parent] > tree.group_level[own])
    assert np.all(tree.group_boxes[parent, 0] <= tree.group_boxes[own, 0])
    assert np.all(tree.group_boxes[parent, 1] >= tree.group_boxes[own, 1]), "a group's box holds its inputs'"
    assert np.all(tree.leaf_group >= 0), "every leaf is simplified (errors start at 0 at full detail)"
    leaf_boxes = np.array([[scene.chunks.boxes[a:b, 0].min(axis=0), scene.chunks.boxes[a:b, 1].max(axis=0)]
                           for a, b in zip(tree.leaf_first_chunk, tree.leaf_end_chunk, strict=True)])
    assert np.all(tree.group_boxes[tree.leaf_group, 0] <= leaf_boxes[:, 0])
    assert np.all(tree.group_boxes[tree.leaf_group, 1] >= leaf_boxes[:, 1])


def test_each_level_at_most_halves_down_to_a_few_clusters(dragon):
    """The groups change from level to level, so no border stays locked at full detail: each level
    keeps at most half the triangles of the one below, down to a few clusters."""
    scene, tree = dragon
    per_level = [scene.triangle_count] + [int(tree.triangles[tree.level == level].sum())
                                          for level in range(1, int(tree.group_level.max()) + 1)]
    assert all(b <= 0.5 * a for a, b in itertools.pairwise(per_level)), per_level
    assert per_level[-1] <= 0.01 * scene.triangle_count and np.sum(tree.parent < 0) <= 4


def test_a_clusters_triangles_stay_within_its_box_and_its_groups(dragon):
    scene, tree = dragon
    (batch,) = scene.batches
    for node in range(tree.node_count):
        faces = tree.indices[tree.index_bounds[node]:tree.index_bounds[node + 1]].reshape(-1, 3)
        corners = batch.positions[faces.reshape(-1)]
        assert np.all(corners >= tree.boxes[node, 0]) and np.all(corners <= tree.boxes[node, 1])
        box = tree.group_boxes[tree.own[node]]
        assert np.all(corners >= box[0]) and np.all(corners <= box[1])
    parts = tree.cluster_parts
    assert np.array_equal(tree.part_bounds[parts], tree.index_bounds), "a cluster's parts tile its indices"
    assert np.all(np.diff(tree.part_bounds) <= 3 * PART_FACES) and np.all(np.diff(tree.part_bounds) > 0)
    for part in range(tree.part_boxes.shape[0]):
        corners = batch.positions[tree.indices[tree.part_bounds[part]:tree.part_bounds[part + 1]]]
        assert np.all(corners >= tree.part_boxes[part, 0]) and np.all(corners <= tree.part_boxes[part, 1])


def test_the_levels_cost_at_most_40_percent_more_memory(dragon):
    scene, tree = dragon
    assert tree.indices.nbytes <= 0.4 * scene.gpu_bytes


def drawn_area(cut: LodCut, tree: LodTree, scene: SceneData) -> float:
    """The area of what a frame at ``cut`` draws: its clusters and the chunks left at full detail."""
    (batch,) = scene.batches
    positions = batch.positions.astype(np.float64)

    def area(faces: np.ndarray) -> float:
        a, b, c = (positions[faces.reshape(-1, 3)[:, k]] for k in range(3))
        return float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum() / 2)

    first, end = subtract_ranges(np.zeros(1, np.int64), np.array([scene.chunks.chunk_count]), cut.blocked_first,
                                 cut.blocked_end)
    index = scene.chunks.index_bounds
    full = sum(area(batch.faces.reshape(-1)[index[a]:index[b]]) for a, b in zip(first, end, strict=True))
    return full + sum(area(tree.indices[tree.index_bounds[n]:tree.index_bounds[n + 1]]) for n in cut.nodes)


def test_a_cut_covers_the_model_once_and_depends_on_the_camera_alone(dragon):
    scene, tree = dragon
    cameras = random_cameras(scene.bounds, 30, seed=5, nearest=0.05)
    whole = drawn_area(LodCut.full(), tree, scene)
    kinds = set()
    for camera in cameras:
        for error in (0.5, 2.0, 16.0):
            cut = lod_cut(tree, camera, (1280, 720), error)
            again = lod_cut(tree, Camera.from_json(camera.to_json()), (1280, 720), error)
            assert np.array_equal(cut.nodes, again.nodes), "the same camera gives the same cut"
            assert np.array_equal(cut.blocked_first, again.blocked_first)
            fits = projected_errors(tree, camera, (1280, 720)) <= error
            has_parent = tree.parent >= 0
            assert np.all(fits[tree.own[has_parent]] | ~fits[tree.parent[has_parent]]), \
                "a group fits only where its inputs do: the cut is closed"
            assert np.all(fits[tree.own[cut.nodes]]), "a chosen cluster is within the bound"
            parents = tree.parent[cut.nodes]
            assert not np.any(fits[parents[parents >= 0]]), "its parent is not: it is the coarsest that fits"
            blocked = fits[tree.leaf_group]
            assert np.array_equal(cut.blocked_first, tree.leaf_first_chunk[blocked])
            area = drawn_area(cut, tree, scene) / whole   # a coarse level loses a little of a scan's area
            assert (0.98 if error <= 2.0 else 0.9) <= area <= 1.01, f"drawn once, no part missing ({area})"
            levels = tree.level[cut.nodes]
            kinds.add((cut.coarse, bool(cut.nodes.size) and levels.min() != levels.max()))
    assert (True, True) in kinds, "some cut mixes levels"
    assert not lod_cut(tree, cameras[0], (1280, 720), 0.0).coarse, "no bound: full detail"


def test_a_cut_of_a_flat_model_covers_it_exactly_once():
    """A flat square keeps its area exactly at any level (its border is locked): a cut covers it
    exactly once, from any camera, at any bound (its errors are 0: an eye in its plane, inside the
    boxes of the groups around it, keeps those at full detail). 400 cells a side: enough groups that
    an eye in its plane lies outside some coarse ones (at 200 both level-2 groups span the square)."""
    scene = grid_plane(400)
    tree = build_lod(scene, lambda fraction, message: None)
    assert tree.group_level.max() >= 3
    cameras = [Camera(eye=(x, y, z), target=(0.5, 0.5, 0.0), up=(0.0, 0.0, 1.0), fovy_deg=60.0)
               for x, y, z in ((0.5, -0.35, 0.25), (0.1, 0.1, 0.0), (0.9, 0.5, 2.0), (0.6, 0.3, 0.0))]
    seen = set()
    for camera in cameras:
        for error in (0.25, 2.0, 64.0):
            cut = lod_cut(tree, camera, (640, 480), error)
            seen.add(tuple(np.unique(tree.level[cut.nodes]).tolist()))
            assert drawn_area(cut, tree, scene) == pytest.approx(1.0, abs=1e-6)
    assert len(seen) >= 2 and max(len(levels) for levels in seen) >= 2, seen


ranges = st.lists(st.integers(0, 60), max_size=12).map(lambda v: np.unique(np.array(v, np.int64)))


def as_pairs(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    points = points[: points.size // 2 * 2]
    return points[0::2], points[1::2]


@settings(max_examples=200, deadline=None)
@given(ranges, ranges)
def test_subtract_ranges_is_set_difference(kept, cut):
    first, end = as_pairs(kept)
    cut_first, cut_end = as_pairs(cut)
    expected = np.zeros(64, bool)
    for a, b in zip(first, end, strict=True):
        expected[a:b] = True
    for a, b in zip(cut_first, cut_end, strict=True):
        expected[a:b] = False
    got_first, got_end = subtract_ranges(first, end, cut_first, cut_end)
    got = np.zeros(64, bool)
    for a, b in zip(got_first, got_end, strict=True):
        assert a < b
        got[a:b] = True
    assert np.array_equal(got, expected)
    assert np.all(got_first[1:] >= got_end[:-1]), "sorted and disjoint"


def close_camera(scene: SceneData) -> Camera:
    """A camera low over the model's near end, so that near parts are fine and far ones coarse."""
    lo, hi = scene.bounds
    center = (lo + hi) / 2
    radius = float(np.linalg.norm(hi - lo)) / 2
    return Camera(eye=tuple((center + np.array([0.3, 0.25, 0.7]) * radius).tolist()),
                  target=tuple(center.tolist()), up=(0.0, 1.0, 0.0), fovy_deg=50.0)


@pytest.mark.gl
def test_tiles_at_mixed_levels_join_as_the_whole_frame(ctx, dragon):
    scene, tree = dragon
    renderer = TileRenderer(ctx, scene)
    renderer.attach_lod(tree)
    size, camera = (200, 150), close_camera(scene)
    cut = renderer.level_cut(camera, size, 1.5)
    assert cut.coarse and not renderer.level_cut(camera, size, 0.0).coarse
    whole = renderer.render_frame(camera, size, lod_error_px=1.5)
    assert whole.triangles < scene.triangle_count
    stitched = np.zeros_like(whole.pixels)
    for x, w in ((0, 67), (67, 70), (137, 63)):
        for y, h in ((0, 71), (71, 79)):
            tile = renderer.render_tile(camera, size, Rect(x, y, w, h), lod_error_px=1.5)
            stitched[y:y + h, x:x + w] = tile.pixels
    assert np.array_equal(stitched, whole.pixels)
    renderer.release()


@pytest.mark.gl
def test_coarse_clusters_are_drawn_nearest_first(ctx, dragon):
    """As chunks are (node.culling.order): a fragment behind what is drawn is not shaded (before,
    in cluster order: a far cluster drawn first had its fragments shaded, then covered)."""
    scene, tree = dragon
    renderer = TileRenderer(ctx, scene)
    renderer.attach_lod(tree)
    size, camera = (200, 150), close_camera(scene)
    cut = renderer.level_cut(camera, size, 1.5)
    matrix = view_projection(camera, size, scene.bounds)
    assert renderer.lod is not None
    runs = renderer.lod.tile_runs(cut, matrix, size, Rect(0, 0, *size), None, np.zeros(1, bool))
    nodes = np.searchsorted(tree.index_bounds, runs.first, side="right") - 1
    assert np.all(runs.first + runs.count <= tree.index_bounds[nodes + 1]), "a run within one cluster"
    drawn_nodes = nodes[np.diff(nodes, prepend=-1) != 0]
    assert np.array_equal(np.sort(drawn_nodes), cut.nodes), "every cluster of the cut in view, once"
    depth = tree.boxes[drawn_nodes].astype(np.float64).mean(axis=1) @ matrix[3, :3]
    assert drawn_nodes.size > 10 and np.all(np.diff(depth) >= 0.0)
    renderer.release()


@pytest.mark.gl
def test_tiles_draw_about_the_coarse_triangles_of_the_whole_frame(ctx, dragon):
    """A tile draws the parts of a coarse cluster that touch it, not the whole cluster: six tiles
    draw less than twice what the whole frame draws (1.51 times; with clusters culled whole, 2.53
    times: this small model's coarse triangles are large on screen, the big models' are not)."""
    scene, tree = dragon
    renderer = TileRenderer(ctx, scene)
    renderer.attach_lod(tree)
    size, camera = (1200, 900), default_camera(scene.bounds, aspect=4 / 3)
    cut = renderer.level_cut(camera, size, 2.0)
    matrix = view_projection(camera, size, scene.bounds)
    assert renderer.lod is not None
    whole = renderer.lod.tile_runs(cut, matrix, size, Rect(0, 0, *size), None, np.zeros(1, bool)).triangles
    tiles = sum(renderer.lod.tile_runs(cut, matrix, size, Rect(x, y, 400, 450), None, np.zeros(1, bool)).triangles
                for x in (0, 400, 800) for y in (0, 450))
    assert whole > 10_000 and tiles <= 2.0 * whole, (tiles, whole)
    renderer.release()


@pytest.mark.gl
def test_hybrid_culling_draws_the_levels_on_a_gpu_stint_too(ctx, dragon):
    """Hybrid culling (the default on a hardware GPU) culls a tile with coarse levels on the CPU,
    also while its switch has sent the tile's slot to the GPU: the levels are drawn, as with CPU
    culling, and tiles without levels go on culling on the GPU."""
    scene, tree = dragon
    eager = SwitchParams(threshold_s=1e-12, frames_to_switch=1, gpu_frames=50, check_frames=1)
    hybrid = TileRenderer(ctx, scene, culling=CullMode.HYBRID, switch_params=eager)
    cpu = TileRenderer(ctx, scene, culling=CullMode.CPU)
    for renderer in (hybrid, cpu):
        renderer.attach_lod(tree)
    size, camera, rect = (200, 150), close_camera(scene), Rect(0, 0, 120, 150)
    full = [hybrid.render_tile(camera, size, rect, slot="a") for _ in range(3)]
    assert full[-1].cull_path == "gpu"
    for _ in range(2):
        tile = hybrid.render_tile(camera, size, rect, slot="a", lod_error_px=1.5)
        expected = cpu.render_tile(camera, size, rect, slot="a", lod_error_px=1.5)
        assert tile.cull_path == "cpu" and tile.triangles == expected.triangles < full[-1].triangles
        assert np.array_equal(tile.pixels, expected.pixels)
    assert hybrid.render_tile(camera, size, rect, slot="a").cull_path == "gpu"
    for renderer in (hybrid, cpu):
        renderer.release()


def grid_plane(cells: int, wave: float = 0.0) -> SceneData:
    """A square of ``cells`` x ``cells`` quads (two triangles each), side 1, in z = 0 (flat) or
    rippled ``wave`` high (so that its coarse levels have errors)."""
    u = np.linspace(0.0, 1.0, cells + 1, dtype=np.float32)
    x, y = np.meshgrid(u, u)
    z = (wave * np.sin(40.0 * x) * np.cos(31.0 * y)).astype(np.float32)
    positions = np.stack([x.reshape(-1), y.reshape(-1), z.reshape(-1)], axis=1)
    corner = (np.arange(cells)[None, :] + (cells + 1) * np.arange(cells)[:, None]).reshape(-1)
    faces = np.concatenate([np.stack([corner, corner + 1, corner + cells + 2], axis=1),
                            np.stack([corner, corner + cells + 2, corner + cells + 1], axis=1)]).astype(np.uint32)
    batch = MeshBatch("plane", positions, np.tile(np.float32([0.0, 0.0, 1.0]), (len(positions), 1)), faces)
    return SceneData.from_batches("plane", [batch])


@pytest.mark.gl
def test_a_rippled_sheet_at_two_levels_has_no_crack(ctx):
    scene = grid_plane(200, wave=0.02)
    tree = build_lod(scene, lambda fraction, message: None)
    renderer = TileRenderer(ctx, scene, background=(1.0, 0.0, 1.0))
    renderer.attach_lod(tree)
    size = (320, 240)
    # Low over the near edge, looking across: near nodes fine, far ones coarse.
    camera = Camera(eye=(0.5, -0.05, 0.1), target=(0.5, 0.6, 0.0), up=(0.0, 0.0, 1.0), fovy_deg=60.0)
    cut = renderer.level_cut(camera, size, 1.0)
    levels = set(tree.level[cut.nodes].tolist())
    assert cut.coarse and cut.blocked_first.size < tree.leaf_first_chunk.size and len(levels | {0}) >= 2
    full = renderer.render_frame(camera, size).pixels
    mixed = renderer.render_frame(camera, size, lod_error_px=1.0).pixels
    background = np.all(full == full[0, 0], axis=2)
    inside = ~background
    # The plane's inside, away from its own outline (a coarse level may shift the outline by its error).
    rows = np.nonzero(inside)[0]
    core = np.zeros_like(inside)
    core[rows.min() + 3:rows.max() - 2, :] = True
    core &= np.all([np.roll(inside, shift, axis) for shift in (-3, 3) for axis in (0, 1)], axis=0) & inside
    holes = core & np.all(mixed == full[0, 0], axis=2)
    assert core.sum() > 10_000 and not holes.any(), f"{holes.sum()} background pixels inside the plane"
    renderer.release()


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)


@pytest.mark.gl
@pytest.mark.parametrize("relative", [LUCY, DRAGON, PAN])
def test_the_moving_frame_keeps_to_38_db_against_full_detail(ctx, relative):
    """At the default bound, from the default camera and three random ones, at a small frame size
    (a bound in pixels is coarser there)."""
    scene = load_scene(str(scene_path(relative)))
    tree = build_lod(scene, lambda fraction, message: None)
    renderer = TileRenderer(ctx, scene)
    renderer.attach_lod(tree)
    size = (480, 270)
    cameras = [default_camera(scene.bounds, aspect=size[0] / size[1]), *random_cameras(scene.bounds, 3, seed=9)]
    for camera in cameras:
        full = renderer.render_frame(camera, size).pixels
        moving = renderer.render_frame(camera, size, lod_error_px=DEFAULT_LOD_ERROR_PX)
        assert psnr(moving.pixels, full) >= 38.0
    renderer.release()


def drawn_by_cut(cut: LodCut, tree: LodTree, scene: SceneData) -> int:
    """Triangles a frame at ``cut`` draws (no culling): its coarse nodes' and the rest at full detail."""
    faces = scene.chunks.face_counts
    first, end = subtract_ranges(np.zeros(1, np.int64), np.array([faces.size]), cut.blocked_first, cut.blocked_end)
    return int(tree.triangles[cut.nodes].sum()) + sum(int(faces[a:b].sum()) for a, b in zip(first, end, strict=True))


def test_balancer_predictions_follow_the_triangles_the_levels_draw(dragon):
    scene, tree = dragon
    groups = scene.groups
    errors, triangles, boxes = group_levels(tree, groups.chunk_starts, scene.chunks.face_counts, scene.chunks.boxes)
    assert np.array_equal(triangles[:, 0], groups.counts), "level 0 is full detail"
    assert np.all(np.diff(errors, axis=1) >= 0.0) and np.all(np.diff(triangles, axis=1) <= 1e-6)
    size = (1280, 720)
    nearer = 0
    cameras = random_cameras(scene.bounds, 12, seed=3, nearest=0.3)
    for camera in cameras:
        for bound in (0.5, 2.0):
            drawn = drawn_by_cut(lod_cut(tree, camera, size, bound), tree, scene)
            predicted = level_counts(errors, triangles, boxes, camera, size, bound).sum()
            assert abs(predicted - drawn) <= 0.35 * drawn, (predicted, drawn)
            # (a camera the levels draw at full detail from is predicted exactly, as the full counts do)
            nearer += abs(predicted - drawn) < abs(groups.counts.sum() - drawn) or predicted == drawn
    assert nearer == 2 * len(cameras), "the levels predict better than the full counts"


def test_a_groups_error_counts_the_normals_it_turns():
    """A flat sheet whose normals ripple (as a scan's do) shades like a rippled one: its coarse levels,
    drawn with a few of those normals, must not count as exact (before, a flat sheet's groups had
    error ~0 whatever its normals, and were drawn coarse from any distance)."""
    scene = grid_plane(200)
    (batch,) = scene.batches
    x, y = batch.positions[:, 0], batch.positions[:, 1]
    rippled = np.stack([0.3 * np.sin(40.0 * x), 0.3 * np.cos(31.0 * y), np.ones_like(x)], axis=1)
    batch.normals[:] = rippled / np.linalg.norm(rippled, axis=1, keepdims=True)
    tree = build_lod(scene, lambda fraction, message: None)
    flat = build_lod(grid_plane(200), lambda fraction, message: None)
    assert tree.node_count and flat.node_count
    level_one = tree.group_level == 1
    assert np.all(tree.group_error[level_one] > 100.0 * max(float(flat.group_error.max()), 1e-7)), \
        (tree.group_error[level_one], flat.group_error.max())


def test_a_closed_solid_is_marked_and_an_open_or_inverted_one_is_not(dragon):
    scene, tree = dragon
    assert tree.batch_closed.tolist() == [True], "the dragon scan bounds a solid"
    (batch,) = scene.batches
    positions = np.asarray(batch.positions, np.float32)
    faces = np.asarray(batch.faces).reshape(-1, 3)
    weld = _weld(positions)[0]
    assert closed_surface(faces, weld, positions)
    assert not closed_surface(faces[:, ::-1], weld, positions), "facing inwards"
    assert not closed_surface(np.delete(faces, 1000, axis=0), weld, positions), "a hole"
    assert build_lod(grid_plane(200), lambda fraction, message: None).batch_closed.tolist() == [False], "a sheet"


@pytest.mark.gl
def test_a_moving_frame_leaves_out_the_back_faces_of_closed_solids_only(ctx, dragon):
    """A sheet seen from behind shows its back faces: drawn in every frame, unless its levels said it
    were a closed solid (then a moving frame, never a still, leaves them out). The dragon, closed,
    moves as it did with its back faces drawn but a few silhouette samples."""
    sheet = grid_plane(200)
    tree = build_lod(sheet, lambda fraction, message: None)
    size = (160, 120)
    behind = Camera(eye=(0.5, 0.5, -1.2), target=(0.5, 0.5, 0.0), up=(0.0, 1.0, 0.0), fovy_deg=50.0)
    for closed in (False, True):
        renderer = TileRenderer(ctx, sheet, background=(1.0, 0.0, 1.0))
        renderer.attach_lod(dataclasses.replace(tree, batch_closed=np.array([closed])))
        moving = renderer.render_frame(behind, size, lod_error_px=1.0).pixels
        still = renderer.render_still(behind, size, 1)
        shown = ~np.all(moving == [255, 0, 255], axis=2)
        assert np.all(~np.all(still == [255, 0, 255], axis=2)[40:80, 60:100]), "the still draws the sheet"
        assert shown[40:80, 60:100].all() != closed, (closed, shown.mean())
        renderer.release()
    scene, tree = dragon
    renderer = TileRenderer(ctx, scene)
    renderer.attach_lod(tree)
    size = (480, 270)
    for camera in [default_camera(scene.bounds, aspect=size[0] / size[1]), *random_cameras(scene.bounds, 3, seed=9)]:
        assert renderer.lod.back_culled(camera, size, scene.bounds, 1.0).tolist() == [True]
        culled = renderer.render_frame(camera, size, lod_error_px=1.0).pixels
        renderer.attach_lod(dataclasses.replace(tree, batch_closed=np.array([False])))
        drawn = renderer.render_frame(camera, size, lod_error_px=1.0).pixels
        renderer.attach_lod(tree)
        assert np.any(culled != drawn, axis=2).mean() < 1e-3
    renderer.release()


def test_back_faces_are_hidden_only_from_outside_a_solid_clear_of_the_near_plane():
    camera = Camera(eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), fovy_deg=60.0)
    size, near = (160, 90), 0.1
    boxes = np.array([[[-1.0, -1.0, -5.0], [1.0, 1.0, -3.0]],      # ahead
                      [[0.5, -1.0, -5.0], [2.0, 1.0, 5.0]],        # beside the eye, reaching behind it
                      [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]],       # around the eye
                      [[0.02, -1.0, -5.0], [2.0, 1.0, 5.0]],       # beside, cut open by the near plane
                      [[-1.0, -1.0, -5.0], [1.0, 1.0, -3.0]]])     # ahead, but not closed
    closed = np.array([True, True, True, True, False])
    assert back_faces_hidden(closed, boxes, camera, size, near).tolist() == [True, True, False, False, False]


@pytest.mark.gl
def test_a_sort_last_share_of_a_closed_solid_is_drawn_without_back_faces(ctx, tmp_path):
    """A share of the closed dragon is open by itself, but its levels mark its batch closed as the
    whole dragon's (its back faces lie behind the front faces the other shares draw); moving layers
    leave them out (a layer alone shows less), and the layers merged by depth differ from those drawn
    with them in a few silhouette samples at most."""
    from node.scene.cache_folder import CacheFolder
    from node.scene.ingest import cached_levels, cached_scene, open_entry
    from node.scene.lod import read_lod
    from tessera.wire.messages import ShareSpec

    def no_progress(fraction: float, message: str) -> None:
        pass

    folder, path, weights = CacheFolder(tmp_path), scene_path(DRAGON), (1.0, 1.0, 1.0)
    whole = build_lod(open_entry(cached_scene(path, 192, None, folder, no_progress), "dragon"), no_progress)
    assert whole.batch_closed.tolist() == [True]
    size = (320, 180)
    cameras = [default_camera(whole_bounds := load_scene(str(path)).bounds, aspect=size[0] / size[1]),
               *random_cameras(whole_bounds, 2, seed=4)]
    merged: dict[bool, list[tuple[np.ndarray, np.ndarray]]] = {True: [], False: []}
    alone: dict[bool, list[np.ndarray]] = {True: [], False: []}
    for index in range(len(weights)):
        entry = cached_scene(path, 192, ShareSpec(version=1, index=index, weights=weights), folder, no_progress)
        share, levels = open_entry(entry, "dragon"), cached_levels(entry, folder, no_progress)
        assert levels is not None
        tree = read_lod(levels)
        assert not closed_surface(share.batches[0].faces, _weld(share.batches[0].positions)[0],
                                  share.batches[0].positions), "a share alone is open"
        assert tree.batch_closed.tolist() == [True], "marked closed as the whole dragon is"
        renderer = TileRenderer(ctx, share)
        for closed in (True, False):
            renderer.attach_lod(dataclasses.replace(tree, batch_closed=np.array([closed])))
            hidden = backless_batches(renderer, cameras[0], size, share.bounds, 1.0, whole=True)
            assert (hidden is not None and hidden.tolist() == [True]) == closed
            for number, camera in enumerate(cameras):
                layer = renderer.render_layer(camera, size, Rect(0, 0, *size), lod_error_px=1.0)
                assert layer.depth is not None
                alone[closed].append(layer.pixels)
                if index == 0:
                    merged[closed].append((layer.pixels, layer.depth))
                    continue
                pixels, depth = merged[closed][number]
                nearer = layer.depth < depth
                merged[closed][number] = (np.where(nearer[..., None], layer.pixels, pixels),
                                          np.where(nearer, layer.depth, depth))
        renderer.release()
    for (culled, _), (drawn, _) in zip(merged[True], merged[False], strict=True):
        assert np.any(drawn != [0, 0, 0], axis=2).mean() > 0.05, "the dragon is in the frame"
        assert np.any(culled != drawn, axis=2).mean() < 1e-3
    # A share's layer alone shows the back faces of the far side of its cut, where another share
    # draws the front: left out, the layers alone differ.
    assert max(np.any(a != b, axis=2).mean() for a, b in zip(alone[True], alone[False], strict=True)) > 0.01
