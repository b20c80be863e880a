"""Smooth vertex normals of a triangle mesh in linear time (issue 31): the face pass of
:mod:`node.scene.face_pass` over the mesh as one chunk. No GL here."""

from __future__ import annotations

import numpy as np

from node.scene.face_pass import face_pass, normalized

__all__ = ["normalized", "smooth_vertex_normals"]


def smooth_vertex_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted smooth normals (V, 3) float32, unit length (zero for a vertex no face with an
    area uses), of ``positions`` (V, 3) and ``faces`` (F, 3); the same whatever the faces' order."""
    if len(faces) == 0:
        return np.zeros((len(positions), 3), np.float32)
    normals = face_pass(positions, np.asarray(faces), np.zeros(1, np.int64)).normals
    assert normals is not None
    return normals
