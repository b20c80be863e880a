"""Point clouds read and ingested (issue 36): LAS/LAZ and PLY points, the octree (every point once,
coarse levels a spatially even subsample, survey coordinates kept to the millimetre), the scene
cache entry (round trip, corrupt entries refused, built once, shares), the budget's choice and
eye-dome lighting (pure)."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from node.scene import compiled
from node.scene.cache import CacheError
from node.scene.cache_folder import CacheFolder
from node.scene.ingest import open_cached, read_scene
from node.scene.loading import load_scene
from node.scene.mesh import SceneError
from node.scene.point_cache import (
    cached_points,
    keep_point_share,
    open_points_entry,
    points_entry_name,
    write_points_entry,
)
from node.scene.point_files import PointArrays, is_point_file, read_points
from node.scene.points import NODE_GRID_BITS, PointCloud, _runs_gathered, _spread_bits, build_octree
from tessera.compositing.eye_dome import eye_dome, guarded_rect, shade_region
from tessera.geometry import Camera, Rect
from tessera.points.budget import pixel_scale, refinement, select_nodes, still_nodes
from tessera.wire.messages import ShareSpec

UTM = np.array([500000.0, 4000000.0, 100.0])


def quiet(fraction: float, message: str) -> None:
    pass


def survey(count: int, seed: int = 1) -> np.ndarray:
    """(count, 3) float64: a rolling 300 m terrain at UTM (500000, 4000000, 100), millimetre coordinates."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0.0, 300.0, count), rng.uniform(0.0, 300.0, count)
    z = 5.0 * np.sin(x / 40.0) + rng.normal(0.0, 0.05, count)
    return np.round(np.stack([x, y, z], axis=1) + UTM, 3)


def write_las(path: Path, positions: np.ndarray, rgb: bool = True, point_format: int = 3) -> None:
    header = laspy.LasHeader(point_format=point_format, version="1.4" if point_format >= 6 else "1.2")
    header.offsets, header.scales = UTM, [0.001, 0.001, 0.001]
    data = laspy.LasData(header)
    data.x, data.y, data.z = positions[:, 0], positions[:, 1], positions[:, 2]
    data.intensity = np.arange(len(positions), dtype=np.uint16)
    if rgb:
        data.red = np.full(len(positions), 65535, np.uint16)
        data.green = np.full(len(positions), 32768, np.uint16)
        data.blue = np.zeros(len(positions), np.uint16)
    data.write(str(path))


@pytest.fixture(scope="module")
def cloud() -> PointCloud:
    return build_octree(PointArrays(survey(120_000)), "terrain.laz", quiet)


def test_every_point_is_kept_once_to_the_millimetre(cloud: PointCloud) -> None:
    world = survey(120_000)
    back = cloud.positions.astype(np.float64) + cloud.centre
    assert np.abs(back - np.round(back, 3)).max() < 1e-4      # millimetres survive at UTM eastings
    order = np.lexsort(np.round(world, 3).T)
    again = np.lexsort(np.round(back, 3).T)
    np.testing.assert_array_equal(np.round(world, 3)[order], np.round(back, 3)[again])
    assert cloud.nodes.first[-1] == cloud.point_count == cloud.nodes.tree.counts.sum()


def test_morton_spreading_and_run_gathering_match_their_plain_definitions() -> None:
    values = np.random.default_rng(5).integers(0, 1 << 21, 5000)
    plain = np.zeros(len(values), np.uint64)
    for bit in range(21):      # bit b of the value goes to bit 3b
        plain |= ((values.astype(np.uint64) >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit)
    np.testing.assert_array_equal(_spread_bits(values), plain)
    runs = np.array([3, 1, 4, 2, 5])
    starts = np.concatenate(([0], np.cumsum(runs)[:-1]))
    target = np.array([2, 0, 2, 1, 0])
    per_point = np.repeat(target, runs)
    np.testing.assert_array_equal(_runs_gathered(target, starts, runs), np.argsort(per_point, kind="stable"))


def test_a_big_cloud_takes_the_compiled_keys_and_gets_the_same_octree(cloud: PointCloud,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """From :data:`node.scene.compiled.COMPILED_FACES` points the Morton keys are made and sorted
    by numba's pass (a threshold lowered here): the very same cloud as numpy's."""
    pytest.importorskip("numba")
    monkeypatch.setattr(compiled, "COMPILED_FACES", 1000)
    assert compiled.available(120_000)
    big = build_octree(PointArrays(survey(120_000)), "terrain.laz", quiet)
    for field in ("positions", "colors", "centre", "bounds"):
        np.testing.assert_array_equal(getattr(big, field), getattr(cloud, field))
    for field in ("first", "centres"):
        np.testing.assert_array_equal(getattr(big.nodes, field), getattr(cloud.nodes, field))
    np.testing.assert_array_equal(big.nodes.tree.boxes, cloud.nodes.tree.boxes)


def test_the_root_is_an_even_subsample_and_nodes_hold_their_points(cloud: PointCloud) -> None:
    nodes, tree = cloud.nodes, cloud.nodes.tree
    assert tree.node_count > 1 and tree.depths[0] == 0 and (tree.parents[1:] < np.arange(1, tree.node_count)).all()
    root = cloud.positions[:nodes.first[1]].astype(np.float64)
    cells = np.floor((root - (nodes.centres[0] - nodes.cube / 2)) / nodes.spacing).astype(np.int64)
    assert len(np.unique(cells, axis=0)) == len(root)     # one point per cell of the root's 2^7 grid
    assert len(root) > 0.5 * (1 << NODE_GRID_BITS) ** 2   # a surface fills most of them
    for node in range(tree.node_count):
        points = cloud.positions[nodes.first[node]:nodes.first[node + 1]]
        if len(points):
            assert (points >= tree.boxes[node, 0] - 1e-4).all() and (points <= tree.boxes[node, 1] + 1e-4).all()
            half = nodes.cube / 2.0 ** tree.depths[node] / 2.0
            assert (np.abs(points - nodes.centres[node]) <= half * 1.001).all()


def test_the_budget_chooses_among_the_usable_nodes_only(cloud: PointCloud) -> None:
    """A prefix of the hierarchy order (the nodes a render node uploaded first) bounds the choice,
    which stays closed under parents and within the budget; every node usable is no mask."""
    tree = cloud.world_tree
    centre = cloud.bounds.mean(axis=0)
    camera = Camera(tuple(centre + np.array([-150.0, -150.0, 40.0])), tuple(centre), (0.0, 0.0, 1.0), 50.0)
    usable = np.arange(tree.node_count) < max(tree.node_count // 4, 2)
    for budget in (20_000, 60_000, None):
        chosen = select_nodes(tree, camera, (640, 360), cloud.bounds, budget, usable)
        assert chosen.any() and not (chosen & ~usable).any()
        assert budget is None or tree.counts[chosen].sum() <= budget
        assert chosen[tree.parents[chosen & (tree.parents >= 0)]].all()
        everything = np.ones(tree.node_count, bool)
        np.testing.assert_array_equal(select_nodes(tree, camera, (640, 360), cloud.bounds, budget, everything),
                                      select_nodes(tree, camera, (640, 360), cloud.bounds, budget))


def test_the_budget_takes_the_nearest_first_and_keeps_parents(cloud: PointCloud) -> None:
    tree = cloud.world_tree
    centre = cloud.bounds.mean(axis=0)
    camera = Camera(tuple(centre + np.array([-150.0, -150.0, 40.0])), tuple(centre), (0.0, 0.0, 1.0), 50.0)
    everything = select_nodes(tree, camera, (640, 360), cloud.bounds, None)
    for budget in (1, 20_000, 60_000, 10**9):
        chosen = select_nodes(tree, camera, (640, 360), cloud.bounds, budget)
        assert tree.counts[chosen].sum() <= budget
        assert not (chosen & ~everything).any()
        assert chosen[tree.parents[chosen & (tree.parents >= 0)]].all()     # closed under parents
    chosen = select_nodes(tree, camera, (640, 360), cloud.bounds, 60_000)
    eye = np.asarray(camera.eye)
    distance = np.linalg.norm(np.clip(eye, tree.boxes[:, 0], tree.boxes[:, 1]) - eye, axis=1)
    deep = tree.depths == tree.depths[chosen].max()
    assert distance[deep & chosen].mean() < distance[deep & everything & ~chosen].mean()
    words = refinement(tree, chosen)
    assert (words[~chosen] == 0).all() and words[0] != 0


def test_the_still_draws_each_place_down_to_its_spacing_on_screen(cloud: PointCloud) -> None:
    """A still's nodes: those in view, closed under parents, each below the root there because its
    parent's points lie more than the spacing apart on screen, and each in view left out under a
    chosen parent because they do not; a spacing of 0 is every node in view, a finer one draws more."""
    tree, spacing = cloud.world_tree, cloud.nodes.spacing
    centre = cloud.bounds.mean(axis=0)
    camera = Camera(tuple(centre + np.array([-150.0, -150.0, 40.0])), tuple(centre), (0.0, 0.0, 1.0), 50.0)
    size = (320, 180)
    everything = select_nodes(tree, camera, size, cloud.bounds, None)
    eye = np.asarray(camera.eye)
    distance = np.linalg.norm(np.clip(eye, tree.boxes[:, 0], tree.boxes[:, 1]) - eye, axis=1)
    parent_px = spacing * 2.0 ** (1 - tree.depths) * pixel_scale(camera, size) / distance
    below_root = tree.parents >= 0
    previous = everything
    for spacing_px in (0.0, 0.5, 1.0, 4.0):
        chosen = still_nodes(tree, camera, size, cloud.bounds, spacing, spacing_px=spacing_px, every_point_max=0)
        assert chosen[0] and not (chosen & ~previous).any()
        assert chosen[tree.parents[chosen & below_root]].all()     # closed under parents
        assert (parent_px[chosen & below_root] > spacing_px).all()
        left_out = everything & ~chosen & below_root
        left_out &= chosen[np.maximum(tree.parents, 0)]
        assert (parent_px[left_out] <= spacing_px).all()
        previous = chosen
    np.testing.assert_array_equal(still_nodes(tree, camera, size, cloud.bounds, spacing, spacing_px=0.0), everything)
    assert 1 < tree.counts[previous].sum() < tree.counts[everything].sum() / 2
    usable = np.arange(tree.node_count) < max(tree.node_count // 4, 2)
    assert not (still_nodes(tree, camera, size, cloud.bounds, spacing, usable) & ~usable).any()


def test_the_still_draws_every_point_in_view_where_they_are_few_enough(cloud: PointCloud) -> None:
    """Up to ``every_point_max`` points in view the still draws them all (the picture of every
    point); one fewer, it draws down to its spacing on screen."""
    tree, spacing = cloud.world_tree, cloud.nodes.spacing
    centre = cloud.bounds.mean(axis=0)
    camera = Camera(tuple(centre + np.array([-150.0, -150.0, 40.0])), tuple(centre), (0.0, 0.0, 1.0), 50.0)
    size = (320, 180)
    everything = select_nodes(tree, camera, size, cloud.bounds, None)
    in_view = int(tree.counts[everything].sum())
    np.testing.assert_array_equal(still_nodes(tree, camera, size, cloud.bounds, spacing), everything)
    np.testing.assert_array_equal(still_nodes(tree, camera, size, cloud.bounds, spacing, every_point_max=in_view),
                                  everything)
    spaced = still_nodes(tree, camera, size, cloud.bounds, spacing, every_point_max=in_view - 1, spacing_px=4.0)
    np.testing.assert_array_equal(spaced, still_nodes(tree, camera, size, cloud.bounds, spacing, every_point_max=0,
                                                      spacing_px=4.0))
    assert tree.counts[spaced].sum() < in_view


def test_las_and_laz_files_are_read_with_their_colours(tmp_path: Path) -> None:
    positions = survey(5000)
    for suffix in (".las", ".laz"):
        path = tmp_path / f"scan{suffix}"
        write_las(path, positions)
        assert is_point_file(path)
        points = read_points(path)
        np.testing.assert_allclose(points.positions, positions, atol=1e-6)
        assert (points.colors == [255, 128, 0]).all()
        assert points.intensity is not None and points.intensity[7] == 7


def test_ply_points_are_a_cloud_and_ply_faces_a_mesh(tmp_path: Path) -> None:
    positions = survey(300)
    rgb = np.tile(np.array([[10, 20, 30]], np.uint8), (300, 1))
    for fmt, dtype in (("binary_little_endian", "<"), ("binary_big_endian", ">")):
        path = tmp_path / f"points_{fmt}.ply"
        header = (f"ply\nformat {fmt} 1.0\nelement vertex 300\nproperty double x\nproperty double y\n"
                  "property double z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
        rows = np.zeros(300, [("p", f"{dtype}f8", 3), ("c", "u1", 3)])
        rows["p"], rows["c"] = positions, rgb
        path.write_bytes(header.encode() + rows.tobytes())
        assert is_point_file(path)
        points = read_points(path)
        np.testing.assert_array_equal(points.positions, positions)
        np.testing.assert_array_equal(points.colors, rgb)
    text = tmp_path / "points_ascii.ply"
    body = "\n".join(f"{x} {y} {z} 0.5" for x, y, z in positions[:20])
    text.write_text("ply\nformat ascii 1.0\nelement vertex 20\nproperty float x\nproperty float y\nproperty float z\n"
                    f"property float intensity\nend_header\n{body}\n")
    ascii_points = read_points(text)
    assert ascii_points.count == 20 and ascii_points.intensity is not None
    mesh = tmp_path / "mesh.ply"
    mesh.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    assert not is_point_file(mesh)
    assert load_scene(str(mesh)).triangle_count == 1


def test_broken_point_files_get_one_line_reasons(tmp_path: Path) -> None:
    laz = tmp_path / "broken.laz"
    write_las(laz, survey(20_000))
    laz.write_bytes(laz.read_bytes()[:4000])
    with pytest.raises(SceneError, match=r"broken\.laz: corrupt or unreadable LAZ"):
        read_points(laz)
    junk = tmp_path / "junk.las"
    junk.write_bytes(b"not a las file at all")
    with pytest.raises(SceneError, match=r"junk\.las: corrupt or unreadable LAS"):
        read_points(junk)
    short = tmp_path / "short.ply"
    short.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nproperty float y\n"
                      b"property float z\nend_header\n" + bytes(40))
    with pytest.raises(SceneError, match="truncated"):
        read_points(short)
    with pytest.raises(SceneError, match="a point cloud, not a mesh"):
        load_scene(str(short))


def test_the_cache_entry_round_trips_and_a_corrupt_one_is_refused(tmp_path: Path, cloud: PointCloud) -> None:
    entry = tmp_path / "entry"
    write_points_entry(entry, cloud, {"sha256": "0" * 64, "bytes": 1, "name": "terrain.laz"})
    back = open_points_entry(entry, "terrain.laz")
    np.testing.assert_array_equal(back.positions, cloud.positions)
    np.testing.assert_array_equal(back.colors, cloud.colors)
    np.testing.assert_array_equal(back.nodes.first, cloud.nodes.first)
    np.testing.assert_array_equal(back.nodes.tree.boxes, cloud.nodes.tree.boxes)
    np.testing.assert_array_equal(back.centre, cloud.centre)
    data = bytearray((entry / "positions.npy").read_bytes())
    data[-5] ^= 0xFF
    (entry / "positions.npy").write_bytes(bytes(data))
    with pytest.raises(CacheError, match="checksum"):
        open_points_entry(entry, "terrain.laz")


def test_a_file_is_ingested_once_and_shares_cover_the_cloud(tmp_path: Path) -> None:
    source = tmp_path / "scan.laz"
    write_las(source, survey(40_000))
    folder = CacheFolder(tmp_path / "cache")
    entry = read_scene(str(source), str(source), 192, None, quiet, folder)
    assert isinstance(entry, Path) and entry.name.endswith(points_entry_name("")[-12:])
    built = (entry / "table.json").stat().st_mtime_ns
    again = cached_points(source, None, folder, quiet)
    assert again == entry and (entry / "table.json").stat().st_mtime_ns >= built
    whole = open_cached(entry, "scan.laz")
    assert isinstance(whole, PointCloud) and whole.point_count == 40_000
    weights = (1.0, 2.0, 1.0)
    shares = [open_cached(read_scene(str(source), str(source), 192, ShareSpec(version=1, index=i, weights=weights),
                                     quiet, folder), "scan.laz") for i in range(3)]
    assert sum(share.point_count for share in shares) == 40_000
    for index, share in enumerate(shares):
        assert isinstance(share, PointCloud) and share.share == (index, weights)
        np.testing.assert_array_equal(share.nodes.tree.counts, whole.nodes.tree.counts)   # the whole tree
        memory = keep_point_share(whole, weights, index)
        np.testing.assert_array_equal(memory.positions, share.positions)
    assert 0.25 < shares[1].point_count / 40_000 < 0.75


def test_eye_dome_tiles_equal_the_whole_frame() -> None:
    rng = np.random.default_rng(4)
    size = (97, 61)
    depth = rng.uniform(0.95, 0.999, (61, 97)).astype(np.float32)
    depth[rng.random((61, 97)) < 0.2] = 1.0
    color = rng.integers(0, 256, (61, 97, 3), dtype=np.uint8)
    whole = eye_dome(color, depth, 0.5, 200.0)
    assert (whole[depth == 1.0].sum(axis=-1) == 0).any()      # outlines around points on the background
    for rect in (Rect(0, 0, 40, 30), Rect(40, 0, 57, 30), Rect(13, 30, 70, 31), Rect(96, 60, 1, 1)):
        drawn = guarded_rect(rect, size)
        tile = shade_region(color[drawn.y:drawn.y1, drawn.x:drawn.x1], depth[drawn.y:drawn.y1, drawn.x:drawn.x1],
                            drawn, rect, 0.5, 200.0)
        np.testing.assert_array_equal(tile, whole[rect.y:rect.y1, rect.x:rect.x1])


def test_eye_dome_darkens_what_lies_behind_a_nearer_neighbour() -> None:
    depth = np.full((9, 9), 0.99, np.float32)
    depth[:, :4] = 0.95                       # the left part nearer
    color = np.full((9, 9, 3), 200, np.uint8)
    shaded = eye_dome(color, depth, 1.0, 100.0)
    assert (shaded[1:-1, 6:-1] == 200).all()          # a flat region is unshaded
    assert (shaded[1:-1, 4] < 100).all()              # the far side of the step is darkened
    assert (shaded[1:-1, 3] == 200).all()             # the near side is not


def test_the_upload_check_takes_point_clouds_and_refuses_broken_ones(tmp_path: Path) -> None:
    from server.scene_library import NotAScene, check_scene_file

    good, broken = tmp_path / "good.laz", tmp_path / "broken.las"
    write_las(good, survey(3000))
    write_las(broken, survey(3000), rgb=False, point_format=0)
    broken.write_bytes(broken.read_bytes()[:1500])
    assert check_scene_file(good, "upload/good.laz") == 0
    with pytest.raises(NotAScene, match=r"^upload/broken\.las: corrupt or unreadable LAS"):
        check_scene_file(broken, "upload/broken.las")
