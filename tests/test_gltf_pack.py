"""A .gltf with separate buffer and image files made self-contained (tessera/scene/gltf_pack.py):
the packed file, alone in a folder, loads as the same scene as the original beside its files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from node.scene.loading import load_scene
from tessera.scene.gltf import GltfError
from tessera.scene.gltf_pack import self_contained_gltf
from tests.conftest import scene_path

TRUCK = "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"


def test_the_packed_truck_alone_is_the_truck_with_its_files(tmp_path: Path):
    original = scene_path(TRUCK)
    asked: list[str] = []

    def read_file(uri: str) -> bytes:
        asked.append(uri)
        return (original.parent / uri).read_bytes()

    packed = self_contained_gltf(original.read_bytes(), read_file)
    assert packed is not None and sorted(asked) == ["CesiumMilkTruck.png", "CesiumMilkTruck0.bin"]
    alone = tmp_path / "truck.gltf"
    alone.write_bytes(packed)
    assert "data:image/png;base64," in packed.decode() and self_contained_gltf(packed, read_file) is None
    before, after = load_scene(str(original)), load_scene(str(alone))
    assert after.triangle_count == before.triangle_count > 0
    assert len(after.batches) == len(before.batches)
    for a, b in zip(after.batches, before.batches, strict=True):
        assert np.array_equal(a.positions, b.positions) and np.array_equal(a.faces, b.faces)
        assert (a.texture is None) == (b.texture is None)
        if a.texture is not None:
            assert np.array_equal(a.texture, b.texture)


def test_percent_encoded_uris_are_read_decoded_and_bad_json_is_refused():
    document = {"asset": {"version": "2.0"}, "buffers": [{"uri": "my%20buffer.bin", "byteLength": 3}],
                "images": [{"uri": "a.jpg"}, {"uri": "data:image/png;base64,AAAA"}]}
    files = {"my buffer.bin": b"abc", "a.jpg": b"\xff\xd8"}
    packed = json.loads(self_contained_gltf(json.dumps(document).encode(), files.__getitem__) or b"")
    assert packed["buffers"][0]["uri"] == "data:application/octet-stream;base64,YWJj"
    assert packed["images"][0]["uri"] == "data:image/jpeg;base64,/9g="
    assert packed["images"][1]["uri"] == "data:image/png;base64,AAAA", "inline ones are left alone"
    with pytest.raises(GltfError, match="invalid glTF JSON"):
        self_contained_gltf(b"{not json", files.__getitem__)
