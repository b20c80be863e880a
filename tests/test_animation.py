"""glTF animation sampling (issue 11; glTF 2.0 §3.11, Appendix C) against hand-computed values for
each interpolation, the accessor reader (strides, sparse, normalised integers, GLB, data URIs) and
CesiumMilkTruck's wheel animation."""

from __future__ import annotations

import base64
import json
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tessera.scene.animation import AnimationError, parse_animations, sample_animations
from tessera.scene.gltf import GltfDocument, GltfError, read_document, read_glb
from tessera.scene.state import ObjectPatch
from tests.conftest import scene_path

S45 = math.sqrt(0.5)


class Builder:
    """A glTF document assembled in memory: each array becomes a packed buffer view and accessor."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.json: dict[str, Any] = {"asset": {"version": "2.0"}, "bufferViews": [], "accessors": []}

    def add(self, array: Any, component: int = 5126, normalized: bool = False) -> int:
        dtype = {5126: "<f4", 5122: "<i2", 5123: "<u2"}[component]
        values = np.asarray(array, dtype=dtype)
        values = values.reshape(len(values), -1)
        while len(self.data) % 4:
            self.data.append(0)
        self.json["bufferViews"].append({"buffer": 0, "byteOffset": len(self.data), "byteLength": values.nbytes})
        self.data += values.tobytes()
        kind = {1: "SCALAR", 3: "VEC3", 4: "VEC4"}[values.shape[1]]
        accessor = {"bufferView": len(self.json["bufferViews"]) - 1, "componentType": component,
                    "count": len(values), "type": kind}
        if normalized:
            accessor["normalized"] = True
        self.json["accessors"].append(accessor)
        return len(self.json["accessors"]) - 1

    def animate(self, path: str, times: Any, values: Any, interpolation: str = "LINEAR", node: int = 0,
                **add_options: Any) -> None:
        sampler = {"input": self.add(times), "output": self.add(values, **add_options), "interpolation": interpolation}
        animation = self.json.setdefault("animations", [{"name": "move", "channels": [], "samplers": []}])[0]
        animation["samplers"].append(sampler)
        animation["channels"].append({"sampler": len(animation["samplers"]) - 1,
                                      "target": {"node": node, "path": path}})

    def document(self) -> GltfDocument:
        self.json["buffers"] = [{"byteLength": len(self.data)}]
        return GltfDocument(self.json, (bytes(self.data),))


def sample(builder: Builder, time: float, names: dict[int, str] | None = None) -> ObjectPatch:
    animations = parse_animations(builder.document(), names or {0: "thing"})
    return sample_animations(animations, time)["thing"]


# ---------------------------------------------------------------------------------- interpolation


def test_linear_translation_and_clamping() -> None:
    gltf = Builder()
    gltf.animate("translation", [1.0, 3.0], [[0, 0, 0], [4, 2, -2]])
    assert sample(gltf, 1.5).translation == (1.0, 0.5, -0.5)
    assert sample(gltf, 2.0).translation == (2.0, 1.0, -1.0)
    assert sample(gltf, -5.0).translation == (0.0, 0.0, 0.0)         # before the first keyframe
    assert sample(gltf, 99.0).translation == (4.0, 2.0, -2.0)        # after the last


def test_step_holds_each_keyframe_until_the_next() -> None:
    gltf = Builder()
    gltf.animate("scale", [0.0, 1.0, 2.0], [[1, 1, 1], [2, 2, 2], [3, 3, 3]], "STEP")
    assert sample(gltf, 0.999).scale == (1.0, 1.0, 1.0)
    assert sample(gltf, 1.0).scale == (2.0, 2.0, 2.0)
    assert sample(gltf, 1.5).scale == (2.0, 2.0, 2.0)
    assert sample(gltf, 7.0).scale == (3.0, 3.0, 3.0)


def test_linear_rotation_is_slerp_along_the_shorter_arc() -> None:
    gltf = Builder()
    # 0° → 90° about z, the second keyframe stored negated (the same rotation, the far hemisphere).
    gltf.animate("rotation", [0.0, 1.0], [[0, 0, 0, 1], [0, 0, -S45, -S45]])
    half = sample(gltf, 0.5).rotation                                 # 45°: (0, 0, sin 22.5°, cos 22.5°)
    np.testing.assert_allclose(half, [0.0, 0.0, 0.38268343236509, 0.92387953251129], atol=1e-7)
    third = sample(gltf, 1.0 / 3.0).rotation                          # 30°: (0, 0, sin 15°, cos 15°)
    np.testing.assert_allclose(third, [0.0, 0.0, math.sin(math.radians(15)), math.cos(math.radians(15))], atol=1e-7)


def test_cubic_spline_is_the_hermite_curve_of_the_tangents() -> None:
    gltf = Builder()
    # Keyframes (in-tangent, value, out-tangent) at t = 0 and 2; only x moves. At t = 1: u = 0.5,
    # Δ = 2, basis (0.5, 0.125, 0.5, −0.125): x = 0.5·0 + 2·0.125·1.5 + 0.5·1 + 2·(−0.125)·a₁.
    def keys(in_tangent: float) -> list[list[float]]:
        return [[9, 0, 0], [0, 0, 0], [1.5, 0, 0], [in_tangent, 0, 0], [1, 0, 0], [9, 0, 0]]
    gltf.animate("translation", [0.0, 2.0], keys(0.0), "CUBICSPLINE")
    assert sample(gltf, 1.0).translation == pytest.approx((0.875, 0.0, 0.0))
    assert sample(gltf, 2.5).translation == (1.0, 0.0, 0.0)          # clamped to the value, not a tangent
    assert sample(gltf, -1.0).translation == (0.0, 0.0, 0.0)
    steep = Builder()
    steep.animate("translation", [0.0, 2.0], keys(2.0), "CUBICSPLINE")
    assert sample(steep, 1.0).translation == pytest.approx((0.375, 0.0, 0.0))


def test_cubic_spline_rotation_is_normalised() -> None:
    gltf = Builder()
    zero = [0, 0, 0, 0]
    gltf.animate("rotation", [0.0, 1.0], [zero, [0, 0, 0, 1], zero, zero, [0, 0, S45, S45], zero], "CUBICSPLINE")
    rotation = sample(gltf, 0.5).rotation
    assert rotation is not None
    assert math.hypot(*rotation) == pytest.approx(1.0)
    # Zero tangents: the Hermite weights are (0.5, 0.5): the normalised mean of the two, 45°.
    np.testing.assert_allclose(rotation, [0.0, 0.0, 0.38268343236509, 0.92387953251129], atol=1e-7)


def test_normalised_short_rotations() -> None:
    gltf = Builder()
    gltf.animate("rotation", [0.0, 1.0], [[0, 0, 0, 32767], [0, 0, 32767, 0]], component=5122, normalized=True)
    np.testing.assert_allclose(sample(gltf, 1.0).rotation, [0.0, 0.0, 1.0, 0.0])


def test_channels_of_other_nodes_and_weights_are_skipped() -> None:
    gltf = Builder()
    gltf.animate("translation", [0.0, 1.0], [[0, 0, 0], [1, 1, 1]], node=0)
    gltf.animate("translation", [0.0, 1.0], [[0, 0, 0], [5, 5, 5]], node=7)
    gltf.json["animations"][0]["channels"].append({"sampler": 0, "target": {"node": 0, "path": "weights"}})
    animations = parse_animations(gltf.document(), {0: "thing"})
    assert [(c.target, c.path) for c in animations[0].channels] == [("thing", "translation")]
    assert animations[0].to_json() == {"name": "move", "start": 0.0, "end": 1.0, "targets": ["thing"]}
    assert parse_animations(gltf.document(), {3: "other"}) == ()


@pytest.mark.parametrize(("change", "message"), [
    (lambda j: j["animations"][0]["samplers"][0].update(interpolation="SMOOTH"), "interpolation 'SMOOTH'"),
    (lambda j: j["animations"][0]["channels"][0].update(sampler=5), "sampler 5 does not exist"),
    (lambda j: j["animations"][0]["samplers"][0].update(output=0), "translation output must be 2 values of 3"),
    (lambda j: j["animations"][0]["samplers"][0].update(input=9), "accessor 9 does not exist"),
    (lambda j: j["accessors"][1].update(count=50), "reads past the end"),
])
def test_broken_animations_are_refused(change: Any, message: str) -> None:
    gltf = Builder()
    gltf.animate("translation", [0.0, 1.0], [[0, 0, 0], [1, 1, 1]])
    change(gltf.json)
    with pytest.raises(AnimationError, match=message):
        parse_animations(gltf.document(), {0: "thing"})


def test_decreasing_times_are_refused() -> None:
    gltf = Builder()
    gltf.animate("translation", [1.0, 0.0], [[0, 0, 0], [1, 1, 1]])
    with pytest.raises(AnimationError, match="increasing"):
        parse_animations(gltf.document(), {0: "thing"})


# ------------------------------------------------------------------------------------- accessors


def test_strided_and_sparse_accessors() -> None:
    interleaved = np.arange(12, dtype="<f4").reshape(4, 3)          # rows of (value, pad, pad)
    sparse_rows = np.array([2], "<u2").tobytes() + b"\0\0" + np.array([7.5], "<f4").tobytes()
    data = interleaved.tobytes() + sparse_rows
    document = GltfDocument({
        "buffers": [{"byteLength": len(data)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48, "byteStride": 12},
                        {"buffer": 0, "byteOffset": 48, "byteLength": 2},
                        {"buffer": 0, "byteOffset": 52, "byteLength": 4}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "SCALAR"},
            {"bufferView": 0, "componentType": 5126, "count": 4, "type": "SCALAR",
             "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123}, "values": {"bufferView": 2}}},
            {"componentType": 5126, "count": 3, "type": "SCALAR",
             "sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5123}, "values": {"bufferView": 2}}},
        ],
    }, (data,))
    assert document.accessor(0)[:, 0].tolist() == [0.0, 3.0, 6.0, 9.0]
    assert document.accessor(1)[:, 0].tolist() == [0.0, 3.0, 7.5, 9.0]
    assert document.accessor(2)[:, 0].tolist() == [0.0, 0.0, 7.5]


def glb(document: dict[str, Any], binary: bytes) -> bytes:
    text = json.dumps(document).encode()
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    return b"glTF" + struct.pack("<II", 2, 12 + len(body)) + body


def test_glb_and_data_uri_containers() -> None:
    gltf = Builder()
    gltf.animate("translation", [0.0, 1.0], [[0, 0, 0], [2, 0, 0]])
    gltf.json["buffers"] = [{"byteLength": len(gltf.data)}]
    packed = read_document(glb(gltf.json, bytes(gltf.data)), lambda uri: pytest.fail(f"read {uri}"))
    assert sample_animations(parse_animations(packed, {0: "x"}), 0.25)["x"].translation == (0.5, 0.0, 0.0)
    embedded = dict(gltf.json, buffers=[{"byteLength": len(gltf.data),
                                         "uri": "data:application/octet-stream;base64,"
                                                + base64.b64encode(bytes(gltf.data)).decode()}])
    inline = read_document(json.dumps(embedded).encode(), lambda uri: pytest.fail(f"read {uri}"))
    assert inline.buffers == (bytes(gltf.data),)
    with pytest.raises(GltfError, match="not a GLB"):
        read_glb(b"glTX" + bytes(20))
    with pytest.raises(GltfError, match="truncated"):
        read_glb(glb(gltf.json, bytes(gltf.data))[:-8])


# ---------------------------------------------------------------------------------- the milk truck

TRUCK = "gltf_small/CesiumMilkTruck/CesiumMilkTruck.gltf"


def read_truck() -> GltfDocument:
    path = scene_path(TRUCK)
    return read_document(path.read_bytes(), lambda uri: (path.parent / uri).read_bytes())


def test_milk_truck_wheels() -> None:
    document = read_truck()
    (animation,) = parse_animations(document, {2: "wheels_back", 4: "wheels_front"})
    assert sorted((c.target, c.path, c.sampler.interpolation) for c in animation.channels) == [
        ("wheels_back", "rotation", "LINEAR"), ("wheels_front", "rotation", "LINEAR")]
    assert (animation.start, animation.end) == (0.0, 1.25)
    sampler = animation.channels[0].sampler
    assert sampler.times.shape == (31,) and sampler.values.shape == (31, 4)
    # At t = 0 the wheels are at their nodes' own rotation; at a keyframe exactly, its value.
    start = animation.sample(0.0)
    np.testing.assert_allclose(start["wheels_back"].rotation, document.json["nodes"][2]["rotation"], atol=1e-7)
    keyframe = float(sampler.times[12])
    np.testing.assert_allclose(animation.sample(keyframe)["wheels_front"].rotation, sampler.values[12], atol=1e-12)
    # The wheels turn about z only, a little under a full turn over the 1.25 s.
    middle = animation.sample(0.6)["wheels_back"].rotation
    assert middle is not None and middle[0] == middle[1] == 0.0
    angles = [2 * math.atan2(q[2], q[3]) for q in (animation.sample(t)["wheels_back"].rotation for t in (0.0, 0.6))]
    assert angles[0] != pytest.approx(angles[1], abs=0.5)


def test_milk_truck_as_glb_parses_the_same() -> None:
    document = read_truck()
    packed = dict(document.json, buffers=[{"byteLength": len(document.buffers[0])}])
    again = read_document(glb(packed, document.buffers[0]), lambda uri: pytest.fail(f"read {uri}"))
    names = {2: "a", 4: "b"}
    for time in (0.0, 0.3, 1.0):
        first = sample_animations(parse_animations(document, names), time)
        second = sample_animations(parse_animations(again, names), time)
        assert first == second


def test_real_files_without_animations() -> None:
    path: Path = scene_path("gltf_small/Duck.glb")
    assert parse_animations(read_document(path.read_bytes(), lambda uri: b""), {0: "duck"}) == ()
