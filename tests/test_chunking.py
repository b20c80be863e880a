"""Scene chunks without GL (seed 002 §3.4): the pre-split keeps every triangle exactly once and its
attributes with it, chunks stay under the face limit, blended meshes keep their order, draw runs
never cross a batch, and the coordinator's groups stay few."""

from __future__ import annotations

import numpy as np
import pytest

from node.scene.chunks import MAX_GROUPS, split_batches
from node.scene.data import SceneData
from node.scene.loading import load_scene
from node.scene.mesh import MeshBatch
from node.scene.octree import morton_codes, octree_root
from tests.conftest import scene_path

UNSPLIT = 1 << 40


def triangles_of(scene: SceneData) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle's corner attributes, sorted by them, per batch order: (F, 3·9) positions, uvs and
    colours, and (F, 3·3) the normals in the same order. Smooth normals are summed over a vertex's
    faces in the order the split leaves them, so they may differ in the last bits from the unsplit
    mesh's: compare them with a tolerance."""
    rows, normals = [], []
    for batch in scene.batches:
        uvs = batch.uvs if batch.uvs is not None else np.zeros((batch.vertex_count, 2), np.float32)
        colors = batch.colors if batch.colors is not None else np.ones((batch.vertex_count, 4), np.float32)
        attributes = np.concatenate([batch.positions, uvs, colors], axis=1)
        rows.append(attributes[batch.faces].reshape(batch.triangle_count, -1))
        normals.append(np.asarray(batch.normals)[batch.faces].reshape(batch.triangle_count, -1))
    flat, flat_normals = np.concatenate(rows), np.concatenate(normals)
    order = np.lexsort(np.concatenate([flat, flat_normals], axis=1).T[::-1])
    return flat[order], flat_normals[order]


def assert_same_triangles(a: SceneData, b: SceneData) -> None:
    (corners_a, normals_a), (corners_b, normals_b) = triangles_of(a), triangles_of(b)
    assert np.array_equal(corners_a, corners_b)
    assert np.allclose(normals_a, normals_b, rtol=0.0, atol=1e-6)


def test_split_keeps_every_triangle_once_with_its_attributes():
    spec = str(scene_path("bunny/bun_zipper.ply"))
    whole, split = load_scene(spec, face_limit=UNSPLIT), load_scene(spec, face_limit=512)
    assert whole.chunks.chunk_count == 1 and split.chunks.chunk_count > 69_451 // 512
    assert_same_triangles(split, whole)
    assert np.array_equal(split.bounds, whole.bounds)
    chunks = split.chunks
    faces = chunks.face_counts
    assert faces.sum() == whole.triangle_count and faces.min() >= 1 and faces.max() <= 512
    assert chunks.index_bounds[0] == 0 and np.all(np.diff(chunks.index_bounds) > 0)
    (batch,) = split.batches
    corners = batch.positions[batch.faces]                        # (F, 3, 3)
    chunk_of_face = np.repeat(np.arange(chunks.chunk_count), faces)
    lo = np.full((chunks.chunk_count, 3), np.inf, np.float32)
    np.minimum.at(lo, chunk_of_face, corners.min(axis=1))
    assert np.array_equal(chunks.boxes[:, 0], lo), "chunk boxes are not their faces' bounds"
    codes = morton_codes(batch.positions, *octree_root(batch.positions)).astype(np.int64)
    assert np.all(np.diff(codes) >= 0), "vertices are not in Morton order"


def batch(name: str, faces: int, offset: float, alpha_mode: str = "OPAQUE", seed: int = 0) -> MeshBatch:
    """``faces`` small random triangles in a unit box shifted by ``offset`` along x, coloured by position."""
    rng = np.random.default_rng(seed)
    shift = np.array([offset, 0.0, 0.0])
    corners = rng.uniform(0.0, 1.0, size=(faces, 1, 3)) + rng.normal(scale=0.01, size=(faces, 3, 3))
    positions = (corners.reshape(-1, 3) + shift).astype(np.float32)
    normals = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (3 * faces, 1))
    colors = np.concatenate([np.clip(positions - shift, 0, 1), np.ones((3 * faces, 1))], axis=1)
    return MeshBatch(name, positions, normals, np.arange(3 * faces, dtype=np.uint32).reshape(-1, 3),
                     colors=colors.astype(np.float32), alpha_mode=alpha_mode)


def test_multi_batch_chunks_blended_batches_stay_whole_and_runs_are_cut_per_batch():
    batches = [batch("glass", 900, 4.0, "BLEND", seed=1), batch("a", 1000, 0.0, seed=2), batch("tiny", 40, 2.0),
               batch("b", 700, 6.0, seed=3)]
    scene = SceneData.from_batches("mix", batches, face_limit=100)
    assert [b.name for b in scene.batches] == ["a", "tiny", "b", "glass"]    # blended last
    chunks = scene.chunks
    per_batch = np.diff(chunks.batch_bounds)
    assert per_batch[1] == 1 and per_batch[3] == 1 and per_batch[0] >= 10 and per_batch[2] >= 7
    assert np.array_equal(np.repeat(np.arange(4), per_batch), chunks.batch)
    assert np.array_equal(scene.batches[3].faces, batches[0].faces), "a blended batch was re-ordered"
    for split_batch in scene.batches:   # colour still follows position after the vertex re-ordering
        offset = {"a": 0.0, "tiny": 2.0, "b": 6.0, "glass": 4.0}[split_batch.name]
        expected = np.clip(split_batch.positions - np.array([offset, 0.0, 0.0]), 0, 1)
        assert np.allclose(split_batch.colors[:, :3], expected)

    everything = chunks.all_runs()
    assert everything.batch.tolist() == [0, 1, 2, 3] and everything.chunks == chunks.chunk_count
    assert everything.triangles == scene.triangle_count
    spanning = chunks.runs(np.array([2, per_batch[0] + 1]), np.array([per_batch[0] + 1, chunks.chunk_count]))
    assert spanning.batch.tolist() == [0, 1, 2, 3]                # range 1 ends in batch 1, range 2 covers 2…3
    assert spanning.first[0] == chunks.index_bounds[2]
    assert spanning.first[1] + spanning.count[1] == chunks.index_bounds[per_batch[0] + 1]
    assert spanning.chunks == chunks.chunk_count - 2
    assert spanning.batch_slices() == [(0, 0, 1), (1, 1, 1), (2, 2, 1), (3, 3, 1)]
    split_runs = chunks.runs(np.array([0, 3]), np.array([2, per_batch[0] + 1]))   # two runs in batch 0
    assert split_runs.batch_slices() == [(0, 0, 2), (1, 2, 1)]
    nothing = chunks.runs(np.zeros(0, np.int64), np.zeros(0, np.int64))
    assert nothing.triangles == 0 and nothing.batch_slices() == []


def test_groups_are_chunks_or_merged_runs_of_them():
    scene = SceneData.from_batches("one", [batch("a", 3000, 0.0)], face_limit=30)
    chunks = scene.chunks
    assert 100 < chunks.chunk_count <= MAX_GROUPS
    assert np.array_equal(scene.groups.counts, chunks.face_counts)
    merged = chunks.primitive_groups(max_groups=40)
    assert len(merged.counts) <= 40 and merged.counts.sum() == scene.triangle_count
    assert np.all(merged.boxes[:, :3].min(axis=0) == chunks.boxes[:, 0].min(axis=0))
    assert np.all(merged.boxes[:, 3:].max(axis=0) == chunks.boxes[:, 1].max(axis=0))
    assert MAX_GROUPS <= 4000


def test_groups_never_merge_two_objects():
    scene = SceneData.from_batches("two", [batch("a", 3000, 0.0), batch("b", 3000, 5.0)], face_limit=60)
    chunks = scene.chunks
    assert chunks.chunk_count <= MAX_GROUPS, "the scene's groups are its chunks"
    owners = np.array([b.owner for b in scene.batches])
    assert owners.tolist() == [0, 1] and scene.groups.owners.tolist() == owners[chunks.batch].tolist()
    merged = chunks.primitive_groups(owners, max_groups=7)       # 7 does not divide the chunk runs evenly
    assert len(merged.counts) <= 8 and merged.counts.sum() == scene.triangle_count
    first_of_b = int(np.searchsorted(merged.owners, 1))
    assert merged.owners.tolist() == [0] * first_of_b + [1] * (len(merged.owners) - first_of_b)
    assert merged.counts[:first_of_b].sum() == scene.batches[0].triangle_count


def test_face_limit_must_be_positive():
    with pytest.raises(ValueError):
        split_batches([batch("a", 10, 0.0)], 0)
