"""A binary PLY's faces read by the compiled copy (node.scene.compiled.face_records, for big files)
equal numpy's copy of the file's records, and the same files are refused or handed to the polygon
reader either way."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from node.scene import compiled
from node.scene.mesh import SceneError
from node.scene.ply import read_ply

pytestmark = pytest.mark.skipif(compiled._compiled() is None, reason="numba is not installed")


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, counts: np.ndarray | None = None) -> Path:
    """A binary little-endian PLY of ``vertices`` (V, 3) float32 and ``faces`` (F, 3) int32 (each
    face's count byte ``counts``, 3 by default)."""
    records = np.zeros(len(faces), np.dtype([("n", "u1"), ("v", "<i4", (3,))]))
    records["n"] = 3 if counts is None else counts
    records["v"] = faces
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertices)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
    path.write_bytes(header.encode() + np.asarray(vertices, "<f4").tobytes() + records.tobytes())
    return path


def read_both_ways(path: Path, monkeypatch: pytest.MonkeyPatch) -> list[np.ndarray | str]:
    """The faces read by numpy's copy and by the compiled one (or the one-line reason of either)."""
    found: list[np.ndarray | str] = []
    for threshold in (1 << 62, 1):
        monkeypatch.setattr(compiled, "COMPILED_FACES", threshold)
        try:
            found.append(read_ply(path).faces)
        except SceneError as exc:
            found.append(str(exc))
    return found


def test_compiled_faces_equal_numpys(tmp_path, monkeypatch):
    rng = np.random.default_rng(7)
    vertices = rng.random((5000, 3), np.float32)
    faces = rng.integers(0, 5000, (20_001, 3), dtype=np.int32)
    numpy_faces, compiled_faces = read_both_ways(write_ply(tmp_path / "m.ply", vertices, faces), monkeypatch)
    assert isinstance(compiled_faces, np.ndarray) and compiled_faces.dtype == np.uint32
    assert np.array_equal(numpy_faces, faces) and np.array_equal(compiled_faces, faces)


@pytest.mark.parametrize("index", [5000, -1])
def test_an_index_out_of_range_is_refused_either_way(tmp_path, monkeypatch, index):
    faces = np.tile(np.array([[0, 1, 2]], np.int32), (300, 1))
    faces[299, 1] = index
    found = read_both_ways(write_ply(tmp_path / "bad.ply", np.zeros((5000, 3), np.float32), faces), monkeypatch)
    assert all(isinstance(reason, str) and "face indices out of range" in reason for reason in found), found


def test_a_face_that_is_not_a_triangle_goes_to_the_polygon_reader_either_way(tmp_path, monkeypatch):
    faces = np.tile(np.array([[0, 1, 2]], np.int32), (300, 1))
    counts = np.full(300, 3, np.uint8)
    counts[-1] = 2     # a count the fixed layout cannot hold: not read as triangles
    found = read_both_ways(write_ply(tmp_path / "odd.ply", np.zeros((3, 3), np.float32), faces, counts), monkeypatch)
    assert type(found[0]) is type(found[1])
    if isinstance(found[0], np.ndarray):
        assert np.array_equal(found[0], found[1])
    else:
        assert found[0] == found[1]
