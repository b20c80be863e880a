"""Per-tile CPU frustum culling (seed 001, CPU side): conservative against a brute-force per-triangle
test on a real split scan, exact against a flat per-chunk box test, and hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from node.culling.bvh import build_chunk_bvh, covering_nodes, cull, range_members
from node.culling.frustum import frustum_planes_from_matrix
from node.culling.tiles import indirect_commands
from tessera.geometry import Camera, Rect, view_projection
from tests.culling_support import (
    classify_boxes,
    cull_flat,
    merge_ranges,
    random_cameras,
    random_tiles,
    split_bunny,
    tile_frustum_planes,
)

SIZE = (1280, 720)
GRID_TILES = [Rect(x * 320, y * 180, 320, 180) for y in range(4) for x in range(4)]


@pytest.fixture(scope="module")
def bunny():
    return split_bunny()


def triangle_samples_clip(positions: np.ndarray, faces: np.ndarray, view_proj: np.ndarray) -> np.ndarray:
    """(F, 7, 4) clip coordinates of each triangle's corners, edge midpoints and centroid."""
    clip = np.concatenate([positions.astype(np.float64), np.ones((positions.shape[0], 1))], axis=1) @ view_proj.T
    weights = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5],
                        [1 / 3, 1 / 3, 1 / 3]])
    return np.einsum("sk,fkc->fsc", weights, clip[faces])


def chunks_seen_in_tile(samples: np.ndarray, chunk_of_face: np.ndarray, rect: Rect) -> np.ndarray:
    """Chunks with a triangle sample strictly inside ``rect``'s clip region (no padding): each of
    them draws a pixel of the tile, so culling must keep it."""
    x0, x1 = 2.0 * rect.x / SIZE[0] - 1.0, 2.0 * rect.x1 / SIZE[0] - 1.0
    y0, y1 = 1.0 - 2.0 * rect.y1 / SIZE[1], 1.0 - 2.0 * rect.y / SIZE[1]
    x, y, z, w = np.moveaxis(samples, -1, 0)
    inside = (w > 0) & (np.abs(z) < w) & (x > x0 * w) & (x < x1 * w) & (y > y0 * w) & (y < y1 * w)
    return np.unique(chunk_of_face[inside.any(axis=1)])


def test_culling_never_drops_a_chunk_with_a_triangle_in_the_tile(bunny):
    positions, faces, split, bvh, bounds = bunny
    chunk_of_face = np.repeat(np.arange(split.chunk_count), split.face_counts)
    rng = np.random.default_rng(7)
    kept_total = seen_total = tested = 0
    for camera in random_cameras(bounds, 12, seed=11):
        samples = triangle_samples_clip(positions, faces, view_projection(camera, SIZE, bounds))
        for rect in GRID_TILES + random_tiles(rng, 6, SIZE):
            kept = cull(bvh, tile_frustum_planes(camera, SIZE, rect, bounds)).visible_chunks
            seen = chunks_seen_in_tile(samples, chunk_of_face, rect)
            missing = np.setdiff1d(seen, kept)
            assert missing.size == 0, f"culled visible chunks {missing} for {camera} {rect}"
            kept_total, seen_total, tested = kept_total + kept.size, seen_total + seen.size, tested + 1
    assert seen_total > tested  # the cameras see the model in many tiles
    assert kept_total < 0.5 * tested * split.chunk_count  # and culling removes most chunks per tile


def test_hierarchy_finds_exactly_the_boxes_a_flat_test_keeps(bunny):
    _, _, split, bvh, bounds = bunny
    rng = np.random.default_rng(3)
    for camera in random_cameras(bounds, 10, seed=5):
        for rect in GRID_TILES[::3] + random_tiles(rng, 4, SIZE):
            planes = tile_frustum_planes(camera, SIZE, rect, bounds)
            result = cull(bvh, planes)
            outside, _ = classify_boxes(split.bounds[:, 0].astype(np.float64), split.bounds[:, 1].astype(np.float64),
                                        planes)
            assert np.array_equal(result.visible_chunks, np.flatnonzero(~outside.any(axis=1)))
            assert np.array_equal(cull_flat(bvh, planes), result.visible_chunks)
            covered = range_members(bvh.first_chunk[result.terminal_nodes], bvh.end_chunk[result.terminal_nodes])
            assert np.array_equal(np.sort(covered), np.arange(split.chunk_count)), "terminal nodes are not a cut"
            assert result.chunks_tested <= result.nodes_visited <= bvh.node_count


def test_hidden_ranges_are_left_out_and_their_subtrees_not_walked(bunny):
    """Chunks a frame's coarse levels stand in for: the cull keeps exactly the flat test's chunks
    outside them, the terminal nodes still cover every chunk once, and a tree hidden whole is one
    node's test (a tile drawn at coarse levels walked the tree for chunks it left out)."""
    _, _, split, bvh, bounds = bunny
    rng = np.random.default_rng(9)
    count = split.chunk_count
    for camera in random_cameras(bounds, 6, seed=8):
        for rect in GRID_TILES[::4] + random_tiles(rng, 3, SIZE):
            planes = tile_frustum_planes(camera, SIZE, rect, bounds)
            cuts = np.unique(rng.integers(0, count + 1, 12))
            first, end = cuts[0:-1:2], cuts[1::2]
            hidden_chunks = range_members(first, end)
            result = cull(bvh, planes, (first.astype(np.int64), end.astype(np.int64)))
            plain = cull(bvh, planes)
            assert np.array_equal(result.visible_chunks, np.setdiff1d(plain.visible_chunks, hidden_chunks))
            covered = range_members(bvh.first_chunk[result.terminal_nodes], bvh.end_chunk[result.terminal_nodes])
            assert np.array_equal(np.sort(covered), np.arange(count)), "terminal nodes are not a cut"
            assert result.nodes_visited <= plain.nodes_visited
    everything = cull(bvh, tile_frustum_planes(camera, SIZE, GRID_TILES[5], bounds),
                      (np.array([0]), np.array([count])))
    assert everything.visible_count == 0 and everything.nodes_visited == 1


def test_bvh_nodes_cover_contiguous_chunk_ranges_and_contain_their_children(bunny):
    _, _, split, bvh, _ = bunny
    assert bvh.node_count == 2 * split.chunk_count - 1 and bvh.chunk_count == split.chunk_count
    inner = np.flatnonzero(~bvh.is_leaf)
    left, right = bvh.left[inner], bvh.right[inner]
    assert np.array_equal(bvh.first_chunk[left], bvh.first_chunk[inner])
    assert np.array_equal(bvh.end_chunk[left], bvh.first_chunk[right])
    assert np.array_equal(bvh.end_chunk[right], bvh.end_chunk[inner])
    assert np.array_equal(bvh.parent[left], inner) and np.array_equal(bvh.parent[right], inner)
    assert np.all(bvh.lo[inner] <= np.minimum(bvh.lo[left], bvh.lo[right]))
    assert np.all(bvh.hi[inner] >= np.maximum(bvh.hi[left], bvh.hi[right]))
    leaves = np.flatnonzero(bvh.is_leaf)
    assert np.array_equal(np.sort(bvh.first_chunk[leaves]), np.arange(split.chunk_count))
    assert np.array_equal(bvh.lo[leaves], split.bounds[bvh.first_chunk[leaves], 0])


def test_covering_nodes_hold_every_chunk_of_the_ranges_in_few_boxes(bunny):
    _, _, split, bvh, _ = bunny
    count = split.chunk_count
    rng = np.random.default_rng(3)
    cuts = np.unique(rng.integers(0, count + 1, 12))
    first, end = cuts[0:-1:2], cuts[1::2]
    chunks = range_members(first, end)
    for most in (1, 8, 64, count):
        nodes = covering_nodes(bvh, first, end, most)
        assert 0 < nodes.size <= most
        held = range_members(bvh.first_chunk[nodes], bvh.end_chunk[nodes])
        assert np.isin(chunks, held).all(), "every chunk of the ranges lies in a node"
        assert all(np.isin(range_members(bvh.first_chunk[[n]], bvh.end_chunk[[n]]), chunks).any() for n in nodes), \
            "no node without a chunk of the ranges"
        assert np.all(bvh.lo[nodes].min(axis=0) <= split.bounds[chunks, 0].min(axis=0))
    assert np.array_equal(np.sort(covering_nodes(bvh, first, end, count)), np.sort(
        np.flatnonzero(bvh.is_leaf)[np.isin(bvh.first_chunk[bvh.is_leaf], chunks)])), "the leaves when they fit"
    assert covering_nodes(bvh, first[:0], end[:0], 8).size == 0


def cube_row_bvh(centers: np.ndarray, half: float = 0.25):
    boxes = np.stack([centers - half, centers + half], axis=1)
    return build_chunk_bvh(boxes), np.array([centers.min(axis=0) - half, centers.max(axis=0) + half])


def test_chunks_obviously_outside_a_tile_are_culled():
    grid = np.array([(x, y, 0.0) for y in range(-4, 5) for x in range(-4, 5)], dtype=np.float64)
    bvh, bounds = cube_row_bvh(grid)
    camera = Camera(eye=(0.0, 0.0, 10.0), target=(0.0, 0.0, 0.0), fovy_deg=60.0)
    size = (900, 900)
    rect = Rect(450, 450, 100, 100)  # just right of and below the centre: the cube at (0, 0) and its neighbours
    kept = cull(bvh, tile_frustum_planes(camera, size, rect, bounds)).visible_chunks
    kept_centers = {tuple(c) for c in grid[kept, :2].astype(int).tolist()}
    assert kept_centers == {(0, 0), (1, 0), (0, -1), (1, -1)}
    everything = cull(bvh, tile_frustum_planes(camera, size, Rect(0, 0, 900, 900), bounds))
    assert everything.visible_chunks.size == grid.shape[0]
    assert everything.nodes_visited == 1  # the root lies wholly inside: one test, one range


def test_near_and_far_planes_cull():
    row = np.array([(0.0, 0.0, -float(depth)) for depth in range(1, 11)])
    bvh, bounds = cube_row_bvh(row)
    camera = Camera(eye=(0.0, 0.0, 0.0), target=(0.0, 0.0, -1.0), fovy_deg=30.0, near=3.5, far=7.5)
    kept = cull(bvh, tile_frustum_planes(camera, (64, 64), Rect(0, 0, 64, 64), bounds)).visible_chunks
    assert (-row[kept, 2]).tolist() == [4.0, 5.0, 6.0, 7.0]
    behind = Camera(eye=(0.0, 0.0, -20.0), target=(0.0, 0.0, -30.0), fovy_deg=90.0)
    assert cull(bvh, tile_frustum_planes(behind, (64, 64), Rect(0, 0, 64, 64), bounds)).visible_chunks.size == 0


def test_tile_planes_bound_the_tile_pixels_with_padding():
    camera = Camera(eye=(0.3, 0.2, 5.0), target=(0.0, 0.0, 0.0), fovy_deg=50.0)
    view_proj = view_projection(camera, SIZE, np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    rect = Rect(100, 200, 40, 30)
    planes = frustum_planes_from_matrix(view_proj, SIZE, rect, pad_px=1.0)
    assert np.allclose(np.linalg.norm(planes[:, :3], axis=1), 1.0)
    inverse = np.linalg.inv(view_proj)

    def world_point(px: float, py: float, ndc_z: float = 0.0) -> np.ndarray:
        ndc = np.array([2.0 * px / SIZE[0] - 1.0, 1.0 - 2.0 * py / SIZE[1], ndc_z, 1.0])
        point = inverse @ ndc
        return point[:3] / point[3]

    def inside(point: np.ndarray) -> bool:
        return bool(np.all(planes[:, :3] @ point + planes[:, 3] >= 0.0))

    assert inside(world_point(100.0, 200.0)) and inside(world_point(140.0, 230.0))
    assert inside(world_point(99.5, 229.5, 0.99)) and inside(world_point(140.5, 199.5, -0.99))
    assert not inside(world_point(98.5, 215.0)) and not inside(world_point(141.5, 215.0))
    assert not inside(world_point(120.0, 198.5)) and not inside(world_point(120.0, 231.5))


def test_merge_ranges_coalesces_touching_chunks():
    starts = np.array([0, 30, 60, 90, 150])
    ends = np.array([30, 60, 90, 150, 153])
    assert merge_ranges(np.array([4, 0, 1, 3, 1]), starts, ends) == [(0, 60), (90, 63)]
    assert merge_ranges(np.array([2]), starts, ends) == [(60, 30)]
    assert merge_ranges(np.zeros(0, np.int64), starts, ends) == []
    gapped_ends = np.array([30, 50, 90, 150, 153])  # chunk 1 stops short of chunk 2
    assert merge_ranges(np.array([0, 1, 2]), starts, gapped_ends) == [(0, 50), (60, 30)]


def test_indirect_commands_layout():
    commands = indirect_commands([(0, 60), (90, 63)], base_vertex=7)
    assert commands.dtype == np.uint32 and commands.shape == (2, 5)
    assert commands.tolist() == [[60, 1, 0, 7, 0], [63, 1, 90, 7, 0]]
    assert indirect_commands([]).shape == (0, 5)
