"""What :meth:`tessera.client.Tessera.upload` sends: a file's bytes, or a mesh written to a GLB in
memory (trimesh's exporter; nothing touches the disk)."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

#: What ``upload`` takes: a file path, a ``trimesh.Trimesh`` or ``trimesh.Scene``, or arrays
#: ``(vertices, faces[, normals[, colors]])``.
MeshSource = str | Path | trimesh.Trimesh | trimesh.Scene | Sequence[Any]


def mesh_from_arrays(vertices: Any, faces: Any, normals: Any = None, colors: Any = None) -> trimesh.Trimesh:
    """A mesh of ``vertices`` (N×3 float, scene units), ``faces`` (M×3 int, indices into
    ``vertices``), optional per-vertex ``normals`` (N×3) and ``colors`` (N×3 or N×4, uint8 0–255 or
    float 0–1). ValueError for arrays of the wrong shape or indices out of range."""
    vertices = np.asarray(vertices, dtype=np.float32)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or not len(vertices):
        raise ValueError(f"vertices must be an N×3 array, got shape {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not len(faces) or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be an M×3 integer array, got shape {faces.shape} {faces.dtype}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError(f"faces index vertices 0…{len(vertices) - 1}, got {faces.min()}…{faces.max()}")
    if not np.isfinite(vertices).all():
        raise ValueError("vertices must be finite")
    options: dict[str, Any] = {}
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32)
        if normals.shape != vertices.shape:
            raise ValueError(f"normals must be N×3 like vertices {vertices.shape}, got {normals.shape}")
        options["vertex_normals"] = normals
    if colors is not None:
        options["vertex_colors"] = vertex_colors(colors, len(vertices))
    return trimesh.Trimesh(vertices=vertices, faces=faces.astype(np.int64), process=False, **options)


def vertex_colors(colors: Any, count: int) -> np.ndarray:
    """``colors`` (count×3 or count×4; floats 0–1 or integers 0–255) as count×4 uint8 RGBA."""
    colors = np.asarray(colors)
    if colors.ndim != 2 or colors.shape[0] != count or colors.shape[1] not in (3, 4):
        raise ValueError(f"colors must be N×3 or N×4 for {count} vertices, got shape {colors.shape}")
    if np.issubdtype(colors.dtype, np.floating):
        colors = np.round(np.clip(colors, 0.0, 1.0) * 255.0)
    rgba = np.full((count, 4), 255, dtype=np.uint8)
    rgba[:, :colors.shape[1]] = np.clip(colors, 0, 255).astype(np.uint8)
    return rgba


def glb_bytes(mesh: trimesh.Trimesh | trimesh.Scene, include_normals: bool | None = None) -> bytes:
    """``mesh`` as a binary glTF; ``include_normals`` None: its normals when trimesh holds them."""
    data = mesh.export(file_type="glb", include_normals=include_normals)
    assert isinstance(data, bytes)
    return data


def upload_body(source: MeshSource, name: str | None = None) -> tuple[str, bytes]:
    """(file name, bytes) to upload for ``source``: a path's own bytes (its name unless ``name``),
    or a GLB of a mesh or arrays named ``name`` or ``mesh-<sha256 prefix>.glb`` (one name per
    content: the same mesh twice is one scene)."""
    if isinstance(source, (str, Path)):
        path = Path(source).expanduser()
        return name or path.name, path.read_bytes()
    if isinstance(source, (trimesh.Trimesh, trimesh.Scene)):
        data = glb_bytes(source)
    elif isinstance(source, Sequence) and 2 <= len(source) <= 4:
        data = glb_bytes(mesh_from_arrays(*source), include_normals=(len(source) > 2 and source[2] is not None) or None)
    else:
        raise TypeError("upload takes a path, a trimesh.Trimesh or Scene, or (vertices, faces[, normals[, colors]]), "
                        f"not {type(source).__name__}")
    if name is None:
        name = f"mesh-{hashlib.sha256(data).hexdigest()[:16]}.glb"
    elif not name.lower().endswith(".glb"):
        name += ".glb"
    return name, data
