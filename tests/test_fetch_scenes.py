"""scripts/fetch-scenes: ``--verify`` against scripts/scenes.sha256 on the real scenes and on a copy
with a byte changed, and the conversions on sources made from the scenes at hand (the download
itself needs hosts this machine cannot reach)."""

from __future__ import annotations

import gzip
import importlib.util
import io
import json
import shutil
import subprocess
import sys

import meshopt
import numpy as np
import pytest
import trimesh

from bench.processes import REPO
from tests.conftest import SCENES, scene_path

FETCH_SCENES = REPO / "scripts" / "fetch-scenes"
_spec = importlib.util.spec_from_file_location("fetch_scenes", REPO / "scripts" / "fetch_scenes.py")
assert _spec is not None and _spec.loader is not None
fetch_scenes = importlib.util.module_from_spec(_spec)
sys.modules["fetch_scenes"] = fetch_scenes
_spec.loader.exec_module(fetch_scenes)

MANIFEST = fetch_scenes.read_manifest()
DIORAMA = "multi_object/sd_macross_city_diorama.glb"
DRAGON = "large_scan/stanford_dragon_vrip_res2_202k.ply"


def run_fetch_scenes(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(FETCH_SCENES), *args], capture_output=True, text=True, timeout=120, check=False)


def test_manifest_names_every_source_and_every_source_a_manifest_file():
    assert {source.target for source in fetch_scenes.SOURCES} == set(MANIFEST)
    assert all(len(digest) == 64 for digests in MANIFEST.values() for digest in digests)


def test_verify_passes_on_the_real_scenes():
    result = run_fetch_scenes("--verify", str(SCENES))
    assert result.returncode == 0, result.stderr
    assert f"all {len(MANIFEST)} scene files match" in result.stdout


@pytest.fixture(scope="module")
def scenes_copy(tmp_path_factory):
    copy = tmp_path_factory.mktemp("scenes")
    for relative in MANIFEST:
        (copy / relative).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(scene_path(relative), copy / relative)
    return copy


def test_verify_names_the_one_file_with_a_changed_byte(scenes_copy):
    duck = scenes_copy / "gltf_small" / "Duck.glb"
    original = duck.read_bytes()
    changed = bytearray(original)
    changed[len(changed) // 2] ^= 0x01
    duck.write_bytes(bytes(changed))
    try:
        result = run_fetch_scenes("--verify", str(scenes_copy))
    finally:
        duck.write_bytes(original)
    assert result.returncode == 1
    assert result.stderr.splitlines() == [line for line in result.stderr.splitlines() if "gltf_small/Duck.glb" in line]
    assert result.stderr.startswith("different: gltf_small/Duck.glb (sha256 ")
    assert run_fetch_scenes("--verify", str(scenes_copy)).returncode == 0


def test_verify_names_a_missing_file(scenes_copy):
    truck_png = scenes_copy / "gltf_small" / "CesiumMilkTruck" / "CesiumMilkTruck.png"
    kept = truck_png.read_bytes()
    truck_png.unlink()
    try:
        result = run_fetch_scenes("--verify", str(scenes_copy))
    finally:
        truck_png.write_bytes(kept)
    assert result.returncode == 1
    assert result.stderr.strip() == "missing: gltf_small/CesiumMilkTruck/CesiumMilkTruck.png"


def test_fetch_from_sources_at_hand_writes_only_files_that_match(tmp_path):
    """The sources that are copies are at hand (the scenes themselves); every other one is missing
    and named, nothing half-written is left."""
    sources = tmp_path / "sources"
    copied = [source for source in fetch_scenes.SOURCES if source.convert is fetch_scenes.copy]
    for source in copied:
        (sources / source.repo / source.path).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(scene_path(source.target), sources / source.repo / source.path)
    out = tmp_path / "scenes"
    problems = fetch_scenes.fetch(out, MANIFEST, sources, log=lambda line: None)
    assert sorted(line.split(":")[1].strip() for line in problems) == sorted(
        source.target for source in fetch_scenes.SOURCES if source.convert is not fetch_scenes.copy)
    assert fetch_scenes.verify(out, {source.target: MANIFEST[source.target] for source in copied}) == []
    assert not list(out.rglob("*.partial"))


def test_a_source_with_another_digest_is_refused(tmp_path):
    bunny = next(source for source in fetch_scenes.SOURCES if source.target == "bunny/bun_zipper.ply")
    (tmp_path / bunny.repo / bunny.path).parent.mkdir(parents=True)
    (tmp_path / bunny.repo / bunny.path).write_bytes(scene_path(bunny.target).read_bytes() + b"\n")
    with pytest.raises(ValueError, match="pinned"):
        fetch_scenes.source_bytes(bunny, tmp_path)


def test_gzip_ascii_ply_converts_to_the_manifest_binary_ply():
    """The dragon's source form (gzip ASCII PLY), written from the shared binary PLY's own values,
    converts back to the manifest's bytes."""
    mesh = trimesh.load(scene_path(DRAGON), process=False)
    vertices = np.asarray(mesh.vertices, np.float32)
    faces = np.asarray(mesh.faces)
    header = (f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    text = io.StringIO()
    np.savetxt(text, vertices, fmt="%.9g")
    np.savetxt(text, np.column_stack([np.full(len(faces), 3), faces]), fmt="%d")
    source = gzip.compress((header + text.getvalue()).encode())
    assert fetch_scenes.sha256(fetch_scenes.gzip_ply_to_binary_ply(source)) in MANIFEST[DRAGON]


def meshopt_compressed(glb: bytes) -> bytes:
    """The GLB as gltfpack ships it: every buffer view compressed with EXT_meshopt_compression into
    buffer 0, the plain data's buffer a fallback of the same length (no bytes)."""
    document, binary = fetch_scenes.read_glb(glb)
    index_views = {document["accessors"][i]["bufferView"]: document["accessors"][i]["componentType"]
                   for mesh in document["meshes"] for p in mesh["primitives"] if "indices" in p
                   for i in [p["indices"]]}
    compressed = []
    offset = 0
    for number, view in enumerate(document["bufferViews"]):
        data = fetch_scenes.view_bytes(document, binary, number)
        if number in index_views:
            dtype = np.uint16 if index_views[number] == 5123 else np.uint32
            values = np.frombuffer(data, dtype)
            mode, stride, encoded = "INDICES", values.itemsize, meshopt.encode_gltf_buffer(values, "INDICES")
        else:
            stride = view["byteStride"]
            mode = "ATTRIBUTES"
            encoded = meshopt.encode_gltf_buffer(np.frombuffer(data, np.uint8).reshape(-1, stride), mode)
        view["buffer"] = 1
        view["extensions"] = {fetch_scenes.MESHOPT: {"buffer": 0, "byteOffset": offset, "byteLength": len(encoded),
                                                     "byteStride": stride, "mode": mode,
                                                     "count": len(data) // stride}}
        compressed.append(encoded + b"\0" * (-len(encoded) % 4))
        offset += len(compressed[-1])
    body = b"".join(compressed)
    document["buffers"] = [{"byteLength": len(body)},
                           {"byteLength": len(binary), "extensions": {fetch_scenes.MESHOPT: {"fallback": True}}}]
    document["extensionsUsed"] = [fetch_scenes.MESHOPT]
    document["extensionsRequired"] = [fetch_scenes.MESHOPT]
    return fetch_scenes.write_glb(document, body)


def test_meshopt_glb_decodes_to_the_manifest_glb():
    original = scene_path(DIORAMA).read_bytes()
    source = meshopt_compressed(original)
    assert len(source) < len(original) and fetch_scenes.MESHOPT.encode() in source
    assert fetch_scenes.sha256(fetch_scenes.meshopt_glb_decode(source)) in MANIFEST[DIORAMA]


def test_draco_glb_decodes_to_the_mesh_it_encodes():
    """A Draco GLB of the bunny (one node with a translation) converts to a binary PLY of the same
    triangles, placed by the node, within the encoding's quantisation."""
    import DracoPy

    bunny = trimesh.load(scene_path("bunny/bun_zipper.ply"), process=False)
    encoded = DracoPy.encode(np.asarray(bunny.vertices, np.float32), np.asarray(bunny.faces, np.uint32),
                             quantization_bits=16, preserve_order=True)
    document = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "translation": [1.0, 2.0, 3.0]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4, "extensions": {
            fetch_scenes.DRACO: {"bufferView": 0, "attributes": {"POSITION": 0}}}}]}],
        "accessors": [{"componentType": 5126, "count": len(bunny.vertices), "type": "VEC3"},
                      {"componentType": 5125, "count": 3 * len(bunny.faces), "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteLength": len(encoded)}], "buffers": [{"byteLength": len(encoded)}],
        "extensionsUsed": [fetch_scenes.DRACO], "extensionsRequired": [fetch_scenes.DRACO],
    }
    ply = fetch_scenes.draco_glb_to_ply(fetch_scenes.write_glb(document, encoded))
    assert ply.startswith(b"ply\nformat binary_little_endian 1.0\n")
    converted = trimesh.load(io.BytesIO(ply), file_type="ply", process=False)
    assert len(converted.faces) == len(bunny.faces)
    expected = trimesh.Trimesh(bunny.vertices + np.array([1.0, 2.0, 3.0]), bunny.faces)
    step = np.ptp(bunny.vertices, axis=0).max() / (1 << 16)
    assert np.allclose(converted.vertices, expected.vertices, atol=2 * step)
    assert np.array_equal(converted.faces, expected.faces)


def test_glb_round_trip_keeps_document_and_binary():
    document = json.loads(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 5}]}))
    assert fetch_scenes.read_glb(fetch_scenes.write_glb(document, b"12345")) == (document, b"12345\0\0\0")
