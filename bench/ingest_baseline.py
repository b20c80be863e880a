"""The preprocessing a node ran before the scene cache (issue 31's "today"), kept only as
:mod:`bench.ingest`'s baseline: ``trimesh.load(process=False)``, then per mesh the world transform, smooth
normals by one ``bincount`` per axis and corner, the octree by the Morton codes of face centroids
(21 bits an axis, ``argsort``, one pass over the active faces per level), the vertices renumbered in
the order the faces first use them (``unique``), and 48-byte interleaved vertices (position, normal,
stand-in uv and colour, float32). Not used by the service.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

DEPTH = 21
LIMIT = 192


def _spread_bits(values: np.ndarray) -> np.ndarray:
    v = values.astype(np.uint64) & np.uint64(0x1FFFFF)
    for shift, mask in ((32, 0x1F00000000FFFF), (16, 0x1F0000FF0000FF), (8, 0x100F00F00F00F00F),
                        (4, 0x10C30C30C30C30C3), (2, 0x1249249249249249)):
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


def _normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    corners = positions[faces]
    face_normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    summed = np.zeros((len(positions), 3))
    for axis in range(3):
        for corner in range(3):
            summed[:, axis] += np.bincount(faces[:, corner], weights=face_normals[:, axis], minlength=len(positions))
    lengths = np.linalg.norm(summed, axis=1, keepdims=True)
    return np.divide(summed, lengths, out=np.zeros_like(summed), where=lengths > 0.0)


def _split(positions: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b, c = (positions[faces[:, k]] for k in range(3))
    centroids = (a + b + c) / np.float32(3.0)
    lo = positions.min(axis=0).astype(np.float64)
    extent = max(float((positions.max(axis=0) - lo).max()), np.finfo(np.float64).tiny)
    grid = np.clip(np.floor((centroids - lo) / extent * (1 << DEPTH)), 0, (1 << DEPTH) - 1).astype(np.uint64)
    codes = (_spread_bits(grid[:, 0]) << np.uint64(2)) | (_spread_bits(grid[:, 1]) << np.uint64(1)) | \
        _spread_bits(grid[:, 2])
    order = np.argsort(codes, kind="stable")
    codes = codes[order]
    starts = []
    active = np.arange(len(faces))
    for depth in range(DEPTH + 1):
        prefix = codes[active] >> np.uint64(3 * (DEPTH - depth))
        first = np.flatnonzero(np.concatenate(([True], prefix[1:] != prefix[:-1])))
        counts = np.diff(np.append(first, active.size))
        small = counts <= LIMIT
        starts.append(active[first[small]])
        active = active[np.repeat(~small, counts)]
        if active.size == 0:
            break
    face_lo = np.minimum(np.minimum(a, b), c)[order]
    chunk_starts = np.sort(np.concatenate(starts))
    np.minimum.reduceat(face_lo, chunk_starts, axis=0)
    return order, chunk_starts


def baseline_ingest(path: Path) -> int:
    """Read and preprocess ``path`` as nodes did before the scene cache; returns its triangles."""
    import trimesh

    loaded = trimesh.load(str(path), force="scene", process=False)
    triangles = 0
    for node_name in loaded.graph.nodes_geometry:
        transform, geometry_name = loaded.graph[node_name]
        mesh = loaded.geometry[geometry_name]
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue
        vertices = np.asarray(mesh.vertices, np.float64) @ transform[:3, :3].T + transform[:3, 3]
        faces = np.asarray(mesh.faces, np.int64)
        normals = _normals(vertices, faces).astype(np.float32)
        positions = vertices.astype(np.float32)
        order, _ = _split(positions, faces)
        faces = faces[order]
        used, first_use = np.unique(faces.reshape(-1), return_index=True)
        vertex_order = used[np.argsort(first_use)]
        renumber = np.empty(len(positions), np.int64)
        renumber[vertex_order] = np.arange(vertex_order.size)
        faces = renumber[faces].astype(np.uint32)
        count = vertex_order.size
        np.concatenate([positions[vertex_order], normals[vertex_order], np.zeros((count, 2), np.float32),
                        np.ones((count, 4), np.float32)], axis=1, dtype=np.float32)
        triangles += len(faces)
    return triangles
