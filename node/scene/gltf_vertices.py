"""What trimesh drops of a glTF primitive's vertices: its ``TANGENT`` and ``TEXCOORD_1`` attributes
(glTF 2.0 §3.7.2.1), read from the file's accessors (:class:`tessera.scene.gltf.GltfDocument`). No GL.

trimesh hands over one mesh per primitive with the primitive's vertices as they are (``process=False``),
but not which primitive it came from; a mesh is matched to its primitive by its positions (a digest of
them as float32, the accessor's type): primitives sharing a POSITION accessor share these too.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from tessera.scene.gltf import GltfDocument, GltfError


@dataclass(frozen=True, eq=False)
class VertexExtras:
    """A primitive's ``tangents`` (N, 4) float32 (xyz in the mesh's space, w = ±1 the bitangent's
    sign) and ``uvs1`` (N, 2) float32 (TEXCOORD_1 with the renderer's origin at the bottom left),
    each None when the file has none (or a malformed one)."""

    tangents: np.ndarray | None
    uvs1: np.ndarray | None


def needs_vertex_extras(gltf: dict[str, Any]) -> bool:
    """Whether a glTF JSON has a primitive with TANGENT or TEXCOORD_1 (its buffers are then read)."""
    return any(_extra_attributes(primitive) for primitive in _primitives(gltf))


def position_key(positions: np.ndarray) -> bytes:
    """The digest a mesh's (N, 3) ``positions`` are matched by."""
    return hashlib.blake2b(np.ascontiguousarray(positions, np.float32).tobytes(), digest_size=16).digest()


def vertex_extras(document: GltfDocument) -> dict[bytes, VertexExtras]:
    """The :class:`VertexExtras` of the document's primitives that have any, by :func:`position_key`
    of their positions; a primitive whose accessors cannot be read is left out."""
    found: dict[bytes, VertexExtras] = {}
    for primitive in _primitives(document.json):
        wanted = _extra_attributes(primitive)
        if not wanted:
            continue
        attributes = primitive["attributes"]
        try:
            positions = document.accessor(attributes.get("POSITION"))
            tangents = _accessor(document, attributes.get("TANGENT"), len(positions), 4)
            uvs1 = _accessor(document, attributes.get("TEXCOORD_1"), len(positions), 2)
        except GltfError:
            continue
        if uvs1 is not None:
            uvs1[:, 1] = 1.0 - uvs1[:, 1]
        found.setdefault(position_key(positions), VertexExtras(tangents, uvs1))
    return found


def _accessor(document: GltfDocument, index: Any, count: int, width: int) -> np.ndarray | None:
    if index is None:
        return None
    values = document.accessor(index)
    if values.shape != (count, width):
        return None
    return np.ascontiguousarray(values, np.float32)


def _primitives(gltf: dict[str, Any]) -> list[dict[str, Any]]:
    meshes = gltf.get("meshes")
    lists = [mesh.get("primitives") for mesh in meshes if isinstance(mesh, dict)] if isinstance(meshes, list) else []
    return [primitive for primitives in lists if isinstance(primitives, list) for primitive in primitives
            if isinstance(primitive, dict) and isinstance(primitive.get("attributes"), dict)]


def _extra_attributes(primitive: dict[str, Any]) -> bool:
    return any(name in primitive["attributes"] for name in ("TANGENT", "TEXCOORD_1"))
