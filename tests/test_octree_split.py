"""Octree pre-split (seed 002 §3.4): every face in exactly one chunk, chunks under the limit,
contiguous ranges, tight boxes, octree cells (a face in the cell of its first vertex in Morton
order), the new vertex order; on a synthetic mesh and on the 990k-triangle scan."""

from __future__ import annotations

import numpy as np
import pytest

from node.scene import compiled
from node.scene.face_pass import face_pass
from node.scene.octree import MAX_DEPTH, ChunkSplit, morton_codes, moved_split, octree_root, octree_split
from tests.culling_support import scan_mesh


def random_mesh(face_total: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Small triangles scattered in a box (positions (V, 3) float32, faces (F, 3) uint32)."""
    rng = np.random.default_rng(seed)
    anchors = rng.uniform([-2.0, 0.0, -1.0], [3.0, 1.0, 4.0], size=(face_total, 1, 3))
    positions = (anchors + rng.normal(scale=0.02, size=(face_total, 3, 3))).reshape(-1, 3).astype(np.float32)
    faces = rng.permutation(face_total * 3).astype(np.uint32).reshape(-1, 3)
    return positions, faces


def check_split(positions: np.ndarray, faces: np.ndarray, split: ChunkSplit, face_limit: int) -> None:
    face_total = faces.shape[0]
    assert np.array_equal(np.sort(split.face_order), np.arange(face_total)), "not a permutation of the faces"
    assert split.starts[0] == 0 and split.ends[-1] == face_total
    assert np.array_equal(split.starts[1:], split.ends[:-1]), "chunks are not contiguous ranges"
    assert np.all(split.face_counts >= 1)
    assert split.face_counts.max() <= face_limit
    chunk_of_face = np.repeat(np.arange(split.chunk_count), split.face_counts)
    corners = positions[split.reorder(faces)]                               # (F, 3, 3)
    lo = np.full((split.chunk_count, 3), np.inf, np.float32)
    hi = np.full((split.chunk_count, 3), -np.inf, np.float32)
    np.minimum.at(lo, chunk_of_face, corners.min(axis=1))
    np.maximum.at(hi, chunk_of_face, corners.max(axis=1))
    assert np.array_equal(split.bounds[:, 0], lo), "chunk boxes are not the tight min of their faces"
    assert np.array_equal(split.bounds[:, 1], hi), "chunk boxes are not the tight max of their faces"
    assert np.array_equal(np.sort(split.vertex_order), np.arange(len(positions))), "not a permutation of the vertices"
    assert split.faces.dtype == np.uint32
    assert np.array_equal(split.vertex_order[split.faces], split.reorder(faces)), "renumbered faces differ"


def check_octree_cells(positions: np.ndarray, faces: np.ndarray, split: ChunkSplit, face_limit: int) -> None:
    """Each chunk is one octree cell (of its faces' first vertices in Morton order, which is the new
    vertex order), and it was split only because its parent was over the limit."""
    vertex_codes = morton_codes(positions, *octree_root(positions))[split.vertex_order]
    assert np.all(np.diff(vertex_codes.astype(np.int64)) >= 0), "vertices are not in Morton order"
    codes = vertex_codes[split.faces.min(axis=1)]
    for chunk in range(split.chunk_count):
        depth = int(split.depths[chunk])
        prefixes = codes[split.starts[chunk]:split.ends[chunk]] >> np.uint64(3 * (MAX_DEPTH - depth))
        assert np.all(prefixes == prefixes[0]), f"chunk {chunk} spans several level-{depth} cells"
        if depth > 0:
            parent = prefixes[0] >> np.uint64(3)
            in_parent = np.count_nonzero((codes >> np.uint64(3 * (MAX_DEPTH - depth + 1))) == parent)
            assert in_parent > face_limit, f"chunk {chunk}'s parent cell held only {in_parent} faces"


def test_random_mesh_splits_into_octree_chunks_under_the_limit():
    positions, faces = random_mesh(20_000)
    split = octree_split(positions, faces, face_limit=700)
    check_split(positions, faces, split, 700)
    check_octree_cells(positions, faces, split, 700)
    assert split.chunk_count >= 20_000 // 700


def test_reordered_index_buffer_holds_the_same_triangles():
    positions, faces = random_mesh(3_000, seed=1)
    split = octree_split(positions, faces, face_limit=100)
    reordered = split.reorder(faces)
    assert reordered.dtype == faces.dtype
    assert np.array_equal(reordered, faces[split.face_order])
    assert np.array_equal(np.sort(reordered, axis=0), np.sort(faces, axis=0))


def test_mesh_under_the_limit_is_one_chunk():
    positions, faces = random_mesh(500, seed=2)
    split = octree_split(positions, faces, face_limit=500)
    assert split.chunk_count == 1 and split.depths.tolist() == [0]
    check_split(positions, faces, split, 500)


def test_faces_sharing_one_centroid_are_cut_into_limit_sized_pieces():
    positions, faces = random_mesh(200, seed=3)
    stacked = np.tile(np.array([[0, 1, 2]], np.uint32), (95, 1))  # 95 copies of one triangle
    faces = np.concatenate([faces, stacked])
    split = octree_split(positions, faces, face_limit=10)
    check_split(positions, faces, split, 10)
    copies = np.isin(split.face_order, np.arange(200, 295))
    chunk_of_face = np.repeat(np.arange(split.chunk_count), split.face_counts)
    copy_chunks = np.unique(chunk_of_face[copies])
    assert copy_chunks.size == 10  # ⌈95 / 10⌉ pieces, all at the deepest level
    assert np.all(split.depths[copy_chunks] == MAX_DEPTH)


def test_empty_mesh_and_bad_limits():
    positions, _ = random_mesh(10)
    assert octree_split(positions, np.zeros((0, 3), np.uint32)).chunk_count == 0
    with pytest.raises(ValueError):
        octree_split(positions, np.zeros((1, 3), np.uint32), face_limit=0)
    with pytest.raises(ValueError):
        octree_split(positions, np.zeros((1, 4), np.uint32))


def test_990k_scan_splits_into_chunks_under_the_limit():
    positions, faces = scan_mesh("large_scan/threedscans_pan_990k.ply")
    assert faces.shape[0] > 900_000
    split = octree_split(positions, faces, face_limit=16384)
    check_split(positions, faces, split, 16384)
    assert split.chunk_count > faces.shape[0] // 16384
    assert np.all(split.bounds[:, 0] >= positions.min(axis=0)) and np.all(split.bounds[:, 1] <= positions.max(axis=0))


@pytest.mark.parametrize(("mesh", "face_limit"), [("random", 192), ("random", 1), ("random", 7), ("990k scan", 192)])
def test_compiled_passes_split_as_numpy_does(mesh, face_limit, monkeypatch):
    """Big meshes take the compiled passes (node.scene.compiled): the very same orders, chunks,
    boxes and normals as the numpy passes (a mesh's picture does not depend on its size's path)."""
    if mesh == "random":
        positions, faces = random_mesh(30_000, seed=4)
        faces = np.concatenate([faces, np.tile(np.array([[5, 6, 7]], np.uint32), (300, 1))])   # one cell over the limit
    else:
        positions, faces = scan_mesh("large_scan/threedscans_pan_990k.ply")
    splits = []
    for threshold in (1 << 62, 1):
        monkeypatch.setattr(compiled, "COMPILED_FACES", threshold)
        split = octree_split(positions, faces, face_limit=face_limit, normals=True)
        splits.append((split, moved_split(split, positions * np.float32(1.5), normals=True)))
    assert compiled.available(len(faces))
    for numpy_split, compiled_split in zip(*splits, strict=True):
        for field in ("vertex_order", "face_order", "faces", "starts", "ends", "bounds", "depths", "normals",
                      "positions"):
            assert np.array_equal(getattr(numpy_split, field), getattr(compiled_split, field)), field
    check_split(positions, faces, splits[1][0], face_limit)


@pytest.mark.parametrize("sorted_faces", [True, False])
def test_compiled_face_pass_on_two_threads_sums_as_numpy_does(sorted_faces, monkeypatch):
    """The compiled face pass splits the chunks in two parts, each thread summing the normals of
    its own vertices (shared vertices at the parts' border, faces sorted by their lowest vertex or in
    any order): the same boxes and normals, bit for bit, as the numpy pass."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(7)
    positions = rng.normal(size=(5_000, 3)).astype(np.float32)
    faces = rng.integers(0, 5_000, size=(60_000, 3)).astype(np.uint32)
    if sorted_faces:
        faces = faces[np.argsort(faces.min(axis=1), kind="stable")]
    starts = np.unique(np.concatenate([[0], rng.integers(1, len(faces), 900)]))
    passes = []
    for threshold in (1 << 62, 1):
        monkeypatch.setattr(compiled, "COMPILED_FACES", threshold)
        passes.append(face_pass(positions, faces, starts, normals=True))
    assert np.array_equal(passes[0].boxes, passes[1].boxes)
    assert np.array_equal(passes[0].normals.view(np.uint32), passes[1].normals.view(np.uint32))


@pytest.mark.parametrize("count", [0, 1, 2, 3, 4097, 200_001])
def test_radix_sort_on_two_threads_sorts_as_numpy_does(count):
    """:func:`node.scene.compiled.radix_sort`'s passes on two threads: numpy's sort, stable."""
    pytest.importorskip("numba")
    rng = np.random.default_rng(count)
    for bits in (1, 12, 13, 36):
        keys = (rng.integers(0, 1 << bits, count, dtype=np.uint64) << np.uint64(18)) | np.arange(count, dtype=np.uint64)
        assert np.array_equal(compiled.radix_sort(keys.copy(), 18, bits), np.sort(keys)), bits
