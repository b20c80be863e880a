"""The scene cache (issue 31, node/scene/cache.py, cache_folder.py, ingest.py): an entry opens as the
scene read directly (arrays, chunks, materials, objects, animations); a corrupt, truncated or
other-version entry is built again, never drawn; processes sharing a folder build an entry once;
a builder killed midway leaves no entry; the folder keeps to its bound; the digest of a path is
remembered until the file changes; a share reads only its part; the primitive groups' levels are kept
beside the levels and read back."""

from __future__ import annotations

import json
import multiprocessing
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from node.culling.bvh import ChunkBVH, build_chunk_bvh, bvh_arrays, cull
from node.culling.frustum import frustum_planes_from_matrix
from node.scene.cache import CACHE_FORMAT, TABLE, TREE_PREFIX, CacheError, entry_info, open_entry, share_chunks
from node.scene.cache_folder import CacheFolder, entry_name
from node.scene.data import SceneData
from node.scene.ingest import cached_scene, open_cached, read_scene
from node.scene.loading import load_scene
from node.scene.mesh import SceneError
from tessera.geometry import Rect
from tessera.wire.messages import ShareSpec
from tests.conftest import scene_path, seconds
from tests.integration_support import wait_until

BUNNY = "bunny/bun_zipper.ply"
LUCY = "large_scan/stanford_lucy_240k.ply"
TRUCK = "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"
ENGINE = "gltf_small/2CylinderEngine.glb"
DIORAMA = "multi_object/sd_macross_city_diorama.glb"


def no_progress(fraction: float, message: str) -> None:
    pass


def cached(path: Path, folder: CacheFolder, share: ShareSpec | None = None) -> SceneData:
    entry = read_scene(str(path), str(path), 192, share, no_progress, folder)
    assert isinstance(entry, Path)
    return open_cached(entry, str(path))


def assert_same_tree(kept: ChunkBVH | None, built: ChunkBVH) -> None:
    """The culling tree an entry keeps is the one built over its chunk boxes, array for array."""
    assert kept is not None, "an entry keeps its culling tree"
    mine, theirs = bvh_arrays(kept), bvh_arrays(built)
    assert mine.keys() == theirs.keys()
    for name, array in theirs.items():
        assert mine[name].dtype == array.dtype and np.array_equal(mine[name], array), name
    assert np.array_equal(kept.center, built.center) and np.array_equal(kept.extent, built.extent)


def assert_same_scene(cached_scene: SceneData, direct: SceneData) -> None:
    assert cached_scene.triangle_count == direct.triangle_count
    assert np.array_equal(cached_scene.bounds, direct.bounds)
    for name in ("batch", "index_bounds", "batch_bounds", "boxes"):
        assert np.array_equal(getattr(cached_scene.chunks, name), getattr(direct.chunks, name)), name
    assert_same_tree(cached_scene.chunks.tree, build_chunk_bvh(direct.chunks.boxes))
    assert cached_scene.objects.to_json() == direct.objects.to_json()
    assert [a.keyframes_json() for a in cached_scene.animations] == [a.keyframes_json() for a in direct.animations]
    assert len(cached_scene.batches) == len(direct.batches)
    for a, b in zip(cached_scene.batches, direct.batches, strict=True):
        # trimesh names a glTF's graph nodes anew at each read: the mesh's part of the name is what stays
        assert a.name.split("/")[-1] == b.name.split("/")[-1]
        assert (a.owner, a.alpha_mode, a.alpha_cutoff) == (b.owner, b.alpha_mode, b.alpha_cutoff)
        assert np.array_equal(a.base_color, b.base_color)
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces)
        assert b.normals is not None and np.array_equal(a.normals, b.normals.astype(np.float16))
        for attribute in ("uvs", "colors", "tangents", "uvs1", "texture"):
            mine, theirs = getattr(a, attribute), getattr(b, attribute)
            assert (mine is None) == (theirs is None), attribute
            assert mine is None or np.array_equal(mine, theirs), attribute
        for key in ("metallic", "roughness", "emissive", "normal_scale", "occlusion_strength", "uv_transforms"):
            assert getattr(a.material, key) == getattr(b.material, key), key
        for mine, theirs in zip(a.material.textures(), b.material.textures(), strict=True):
            assert (mine is None) == (theirs is None) and (mine is None or np.array_equal(mine, theirs))


@pytest.mark.parametrize("relative", [BUNNY, TRUCK, ENGINE, DIORAMA])
def test_an_entry_opens_as_the_scene_read_directly(tmp_path, relative):
    path = scene_path(relative)
    folder = CacheFolder(tmp_path / "cache")
    first = cached(path, folder)
    assert_same_scene(first, load_scene(str(path)))
    assert first.geometry is not None and first.nbytes == sum(
        t.nbytes for t in {id(t): t for b in first.batches for t in (b.texture, *b.material.textures())
                           if t is not None}.values()), "only textures are held in memory; geometry is mapped"
    again = cached(path, folder)
    assert_same_scene(again, first)


def corrupt_vertices(entry: Path) -> None:
    path = entry / "vertices.npy"
    data = bytearray(path.read_bytes())
    data[-100] ^= 0xFF
    path.write_bytes(bytes(data))


def truncate_indices(entry: Path) -> None:
    path = entry / "indices.npy"
    path.write_bytes(path.read_bytes()[:-12])


def other_format(entry: Path) -> None:
    table = json.loads((entry / TABLE).read_text())
    table["format"] = CACHE_FORMAT + 1
    (entry / TABLE).write_text(json.dumps(table))


def garbage_table(entry: Path) -> None:
    (entry / TABLE).write_text("{not json")


def corrupt_tree(entry: Path) -> None:
    path = entry / f"{TREE_PREFIX}center_t.npy"
    data = bytearray(path.read_bytes())
    data[-3] ^= 0x40
    path.write_bytes(bytes(data))


def format_1_without_tree(entry: Path) -> None:
    """The entry as format 1 wrote it: no culling tree."""
    table = json.loads((entry / TABLE).read_text())
    for name in [name for name in table["files"] if name.startswith(TREE_PREFIX)]:
        del table["files"][name]
        (entry / f"{name}.npy").unlink()
    table["format"] = 1
    (entry / TABLE).write_text(json.dumps(table))


def tree_missing(entry: Path) -> None:
    (entry / f"{TREE_PREFIX}cut-0.npy").unlink()


@pytest.mark.parametrize("damage", [corrupt_vertices, truncate_indices, other_format, garbage_table, corrupt_tree,
                                    format_1_without_tree, tree_missing])
def test_a_damaged_entry_is_built_again_and_never_opened(tmp_path, damage):
    path = scene_path(BUNNY)
    folder = CacheFolder(tmp_path / "cache")
    first = read_scene(str(path), "bunny", 192, None, no_progress, folder)
    assert isinstance(first, Path)
    damage(first)
    with pytest.raises(CacheError):
        open_entry(first, "bunny", verify=True)
    messages: list[str] = []
    again = read_scene(str(path), "bunny", 192, None, lambda f, m: messages.append(m), folder)
    assert again == first
    assert any(m.startswith("read") for m in messages), "the entry was built again"
    assert_same_scene(open_cached(again, "bunny"), load_scene(str(path)))


def test_a_format_1_entry_is_not_the_one_opened(tmp_path):
    """An entry of format 1 (no culling tree) left in the folder under its own name is never looked
    at: the scene's entry now has another name, built anew."""
    path = scene_path(BUNNY)
    folder = CacheFolder(tmp_path / "cache")
    entry = read_scene(str(path), "bunny", 192, None, no_progress, folder)
    assert isinstance(entry, Path) and entry.name.endswith(f"-v{CACHE_FORMAT}") and CACHE_FORMAT == 2
    format_1_without_tree(entry)
    old = entry.rename(entry.with_name(entry.name[:-len(f"{CACHE_FORMAT}")] + "1"))
    messages: list[str] = []
    again = read_scene(str(path), "bunny", 192, None, lambda f, m: messages.append(m), folder)
    assert again == entry and any(m.startswith("read") for m in messages), "built anew under its own name"
    with pytest.raises(CacheError, match="format 1"):
        open_entry(old, "bunny", verify=False)


def test_the_kept_tree_culls_as_the_built_one(tmp_path):
    """Frustum culls through the tree opened from an entry keep the chunks the tree built over the
    chunk boxes keeps (a share's entry keeps the tree over its own chunks)."""
    path = scene_path(LUCY)
    folder = CacheFolder(tmp_path / "cache")
    rng = np.random.default_rng(3)
    for share in (None, ShareSpec(version=1, index=1, weights=(1.0, 2.0))):
        scene = cached(path, folder, share)
        assert scene.chunks.tree is not None and scene.chunks.tree.chunk_count == scene.chunks.chunk_count > 100
        built = build_chunk_bvh(scene.chunks.boxes)
        bounds = np.asarray(scene.bounds, np.float64)
        centre, extent = bounds.mean(axis=0), bounds[1] - bounds[0]
        for _ in range(5):   # orthographic views of parts of the scene, from the side of +z
            view_proj = np.diag([*(rng.uniform(1.0, 4.0, 2) / extent[:2]), 0.5 / extent[2], 1.0])
            view_proj[:3, 3] = -view_proj[:3, :3] @ (centre + rng.uniform(-0.2, 0.2, 3) * extent)
            planes = frustum_planes_from_matrix(view_proj, (200, 100), Rect(20, 10, 90, 60))
            kept, direct = cull(scene.chunks.tree, planes), cull(built, planes)
            assert np.array_equal(kept.visible_chunks, direct.visible_chunks)
            assert 0 < kept.visible_count < scene.chunks.chunk_count


def build_in_child(path: str, root: str, log: str) -> None:
    """Build (or wait for, then open) the entry of ``path``; write down whether this process read the file."""
    messages: list[str] = []
    entry = read_scene(path, path, 192, None, lambda f, m: messages.append(m), CacheFolder(Path(root)))
    Path(log).write_text(json.dumps({"read": any(m.startswith("read") for m in messages), "entry": str(entry),
                                     "waited": any("waiting for another process" in m for m in messages)}))


def test_processes_sharing_a_folder_build_an_entry_once(tmp_path):
    context = multiprocessing.get_context("spawn")
    logs = [tmp_path / f"log{n}.json" for n in range(3)]
    children = [context.Process(target=build_in_child, args=(str(scene_path(LUCY)), str(tmp_path / "cache"), str(log)))
                for log in logs]
    for child in children:
        child.start()
    for child in children:
        child.join(seconds(120))
        assert child.exitcode == 0
    results = [json.loads(log.read_text()) for log in logs]
    assert sum(r["read"] for r in results) == 1, results
    assert len({r["entry"] for r in results}) == 1
    entries = [p for p in (tmp_path / "cache").iterdir() if p.is_dir() and (p / TABLE).exists()]
    assert len(entries) == 1


def build_and_hang(path: str, root: str) -> None:
    """Build the entry of ``path`` but stop for good before renaming it into place."""
    import node.scene.cache as cache

    def hang(*args: object) -> None:
        threading.Event().wait()

    cache.os.rename = hang  # type: ignore[assignment]
    read_scene(path, path, 192, None, no_progress, CacheFolder(Path(root)))


def test_a_builder_killed_midway_leaves_no_entry_and_the_next_builds_it(tmp_path):
    root = tmp_path / "cache"
    child = multiprocessing.get_context("spawn").Process(target=build_and_hang,
                                                         args=(str(scene_path(BUNNY)), str(root)))
    child.start()
    wait_until(lambda: list(root.glob(".*.tmp/" + TABLE)), seconds(60),
               "the builder to write its whole entry, not yet renamed", interval=0.05)
    child.kill()
    child.join()
    assert not [p for p in root.iterdir() if not p.name.startswith(".") and (p / TABLE).exists()], \
        "no entry without its rename"
    scene = cached(scene_path(BUNNY), CacheFolder(root))
    assert scene.triangle_count == 69_451
    assert not list(root.glob(".*.tmp")), "the next builder removed the killed one's temporary directory"


def test_the_folder_keeps_to_its_bound_dropping_the_least_recently_used(tmp_path):
    root = tmp_path / "cache"
    sizes = {}
    for relative in (BUNNY, LUCY):
        path = read_scene(str(scene_path(relative)), relative, 192, None, no_progress, CacheFolder(root))
        assert isinstance(path, Path)
        sizes[relative] = entry_info(path).bytes
        os.utime(path / TABLE, (time.time() - 100, time.time() - 100))   # the oldest use
    folder = CacheFolder(root, limit_bytes=sizes[BUNNY] + sizes[LUCY] - 1)
    cached(scene_path(BUNNY), folder)       # used again: now the newest
    kept = read_scene(str(scene_path(DIORAMA)), DIORAMA, 192, None, no_progress, folder)
    assert isinstance(kept, Path)
    entries = {p.name for p in root.iterdir() if p.is_dir() and (p / TABLE).exists()}
    assert kept.name in entries and len(entries) < 3
    assert entry_name(folder.content_hash(scene_path(LUCY), no_progress), 192) not in entries, "lucy was used least"


def test_a_paths_digest_is_remembered_until_the_file_changes(tmp_path):
    copy = tmp_path / "model.ply"
    copy.write_bytes(scene_path(BUNNY).read_bytes())
    folder = CacheFolder(tmp_path / "cache")
    hashed: list[str] = []
    first = folder.content_hash(copy, lambda f, m: hashed.append(m))
    assert hashed and folder.content_hash(copy, lambda f, m: hashed.append("again")) == first
    assert "again" not in hashed
    copy.write_bytes(scene_path(BUNNY).read_bytes() + b"\n")
    assert folder.content_hash(copy, no_progress) != first


def test_a_share_is_the_chunks_of_its_part_and_reads_only_them(tmp_path):
    path = scene_path(LUCY)
    folder = CacheFolder(tmp_path / "cache")
    whole = cached(path, folder)
    weights = (1.0, 2.0, 1.0)
    parts = [cached(path, folder, ShareSpec(version=1, index=index, weights=weights)) for index in range(3)]
    assert sum(p.triangle_count for p in parts) == whole.triangle_count
    for index, part in enumerate(parts):
        keep = share_chunks(whole, weights, index)
        assert part.chunks.chunk_count == int(keep.sum())
        assert np.array_equal(part.chunks.boxes, whole.chunks.boxes[keep])
        assert np.array_equal(part.chunks.face_counts, whole.chunks.face_counts[keep])
        assert np.array_equal(part.bounds, whole.bounds) and part.objects.to_json() == whole.objects.to_json()
        (mine,), (theirs,) = part.batches, whole.batches
        corners = mine.positions[mine.faces]
        first = np.flatnonzero(keep)
        expected = np.concatenate([theirs.faces[whole.chunks.index_bounds[c] // 3:whole.chunks.index_bounds[c + 1] // 3]
                                   for c in first])
        assert np.array_equal(corners, theirs.positions[expected]), "the share's triangles are the whole's"
        assert mine.vertex_count == np.unique(expected).size, "only the vertices its faces use"
    assert parts[1].triangle_count > parts[0].triangle_count


def test_a_missing_or_broken_file_gives_its_one_line_reason_and_no_entry(tmp_path):
    folder = CacheFolder(tmp_path / "cache")
    broken = tmp_path / "broken.ply"
    broken.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nend_header\n")
    for path, reason in ((tmp_path / "absent.ply", "no such file"), (broken, "corrupt or unreadable PLY")):
        with pytest.raises(SceneError, match=reason):
            cached_scene(path, 192, None, folder, no_progress) if path.exists() else \
                read_scene(str(path), str(path), 192, None, no_progress, folder)
    assert not [p for p in (tmp_path / "cache").iterdir() if p.is_dir() and (p / TABLE).exists()]


def test_the_groups_levels_are_kept_beside_the_levels_and_read_back(tmp_path, monkeypatch):
    """A node's first frame after a restart waits for its primitive groups' levels (0.37 CPU-s on
    the 24.8M model): worked out once, kept beside the levels entry and read back as they were; a
    damaged one is worked out again."""
    from node.scene import ingest
    from node.scene.ingest import cached_levels, group_levels_name, kept_group_levels
    from node.scene.lod import group_levels, read_lod

    folder = CacheFolder(tmp_path)
    entry = read_scene(str(scene_path(BUNNY)), str(scene_path(BUNNY)), 192, None, no_progress, folder)
    assert isinstance(entry, Path)
    scene = open_cached(entry, "bunny")
    assert isinstance(scene, SceneData)
    levels = cached_levels(entry, folder, no_progress)
    assert levels is not None
    tree = read_lod(levels)
    worked_out = group_levels(tree, scene.groups.chunk_starts, scene.chunks.face_counts, scene.chunks.boxes)
    first = kept_group_levels(folder, levels, tree, scene)
    kept = folder.existing(group_levels_name(levels.name), ingest.GROUP_LEVELS_FORMAT)
    assert kept is not None

    def not_again(*args: object) -> None:
        raise AssertionError("worked out again")

    monkeypatch.setattr(ingest, "group_levels", not_again)
    again = kept_group_levels(folder, levels, tree, scene)
    for made in (first, again):
        assert all(np.array_equal(a, b) and a.dtype == b.dtype for a, b in zip(made, worked_out, strict=True))
    with (kept / "errors.npy").open("r+b") as file:   # one byte of the array changed: its CRC fails
        file.seek(-1, os.SEEK_END)
        last = file.read(1)[0]
        file.seek(-1, os.SEEK_END)
        file.write(bytes([last ^ 0xFF]))
    calls = []
    monkeypatch.setattr(ingest, "group_levels", lambda *args: calls.append(1) or group_levels(*args))
    damaged = kept_group_levels(folder, levels, tree, scene)
    assert calls == [1] and all(np.array_equal(a, b) for a, b in zip(damaged, worked_out, strict=True))


def test_an_ingest_reads_and_writes_with_the_cyclic_collector_paused(tmp_path, monkeypatch):
    """The cyclic collector is off while a file is read and its entry written (its digest given or
    not), and on again after."""
    import gc

    from node.scene import ingest

    collecting = []
    reading = ingest.load_scene

    def load(*args, **kwargs):
        collecting.append(gc.isenabled())
        return reading(*args, **kwargs)

    monkeypatch.setattr(ingest, "load_scene", load)
    folder = CacheFolder(tmp_path / "cache")
    digest = folder.content_hash(scene_path(BUNNY), no_progress)
    cached_scene(scene_path(BUNNY), 192, None, folder, no_progress)
    assert collecting == [False] and gc.isenabled()
    cached_scene(scene_path(BUNNY), 100, None, folder, no_progress, sha256=digest)   # another face limit: built
    assert collecting == [False, False] and gc.isenabled()


def test_a_files_digest_is_its_sha256_read_a_block_at_a_time(tmp_path, monkeypatch):
    """The digest of an empty file, of one block and of several (the last one short), with the bytes
    done reported after each block."""
    import hashlib

    from node.scene import digests

    monkeypatch.setattr(digests, "HASH_BLOCK", 4096)
    for size in (0, 100, 3 * 4096 + 5):
        path = tmp_path / f"file-{size}"
        path.write_bytes(np.random.default_rng(size).integers(0, 256, size, np.uint8).tobytes())
        done: list[int] = []
        assert digests.DigestMemo(None).digest(path, lambda bytes_done, total, done=done: done.append(bytes_done)) \
            == hashlib.sha256(path.read_bytes()).hexdigest()
        assert done == [min(first + 4096, size) for first in range(0, size, 4096)]
