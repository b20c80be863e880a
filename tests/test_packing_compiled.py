"""The compiled vertex packing (node.scene.compiled.interleave): the very bytes numpy's field
assignments give, float16 normals rounded as numpy rounds them."""

import warnings

import numpy as np
import pytest

from node.scene import compiled
from node.scene.mesh import MeshBatch
from node.scene.packing import VertexLayout, pack_vertices

pytest.importorskip("numba")


def test_float16_rounding_is_numpys_for_every_kind_of_float32():
    """Every 997th float32 bit pattern (subnormal halves, ties, overflow, infinities, NaNs) rounds to numpy's bits."""
    values = np.arange(0, 1 << 32, 997, dtype=np.uint64).astype(np.uint32).view(np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # numpy warns of the overflows
        expected = values.astype(np.float16)
    assert np.array_equal(compiled.float16_bits(values).view(np.uint16), expected.view(np.uint16))


@pytest.mark.parametrize("layout", [VertexLayout(), VertexLayout(uvs=True, colors=True)])
def test_compiled_packing_equals_numpys(layout, monkeypatch):
    rng = np.random.default_rng(7)
    count = 50_000
    normals = rng.normal(size=(count, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    normals[:100] *= np.float32(1e-6)                           # subnormal halves
    batches = [MeshBatch("a", rng.normal(size=(count, 3)).astype(np.float32), normals, np.zeros((1, 3), np.uint32),
                         uvs=rng.random((count, 2), np.float32) if layout.uvs else None),
               MeshBatch("b", rng.normal(size=(99, 3)).astype(np.float32), normals[:99], np.zeros((1, 3), np.uint32))]
    packed = []
    for threshold in (1 << 62, 1):
        monkeypatch.setattr(compiled, "COMPILED_FACES", threshold)
        packed.append(pack_vertices(batches, layout))
    assert compiled.available(count)
    assert packed[0].tobytes() == packed[1].tobytes()
