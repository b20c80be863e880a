"""A mesh sent as arrays (issue 33: ``PUT /api/sessions/{id}/mesh``, then coordinator → node), sans-I/O:
arrays in, bytes out, and back, every value checked.

Layout, all little-endian: the magic ``TMSH``, a u32 header length, the header (UTF-8 JSON, padded
with spaces to a multiple of 4 bytes: ``vertices`` N, ``faces`` F, ``normals`` and ``colors``
booleans, and any other keys the sender adds, such as the coordinator's ``scene`` spec), then the
arrays back to back: positions N×3 float32, faces F×3 uint32, normals N×3 float32 (if any),
colors N×4 uint8 RGBA, linear 0–255 as glTF's ``COLOR_0`` (if any).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any, TypeGuard

import numpy as np

MESH_MAGIC = b"TMSH"
#: Spec prefix of a mesh sent as arrays: ``mesh:GROUP:STEP`` (:mod:`server.mesh_updates`).
MESH_PREFIX = "mesh:"
_PREFIX = struct.Struct("<4sI")
#: Longest header (bytes).
MAX_HEADER_BYTES = 4096
#: Largest mesh message a node reads (its socket takes 64 MiB messages; the rest is headroom).
MAX_MESH_BYTES = 60 << 20


class MeshError(ValueError):
    """A mesh that cannot be drawn; the message says what is wrong, in one line."""


@dataclass(frozen=True, eq=False)
class MeshArrays:
    """``positions`` (N, 3) float32 scene units, ``faces`` (F, 3) uint32 indices into them,
    ``normals`` (N, 3) float32 or None, ``colors`` (N, 4) uint8 RGBA (linear, as glTF) or None."""

    positions: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.positions, self.faces, self.normals, self.colors) if a is not None)


def checked_mesh(vertices: Any, faces: Any, normals: Any = None, colors: Any = None) -> MeshArrays:
    """The arrays as :class:`MeshArrays`: ``vertices`` N×3 finite, ``faces`` M×3 integers in 0…N-1,
    ``normals`` N×3 finite, ``colors`` N×3 or N×4 (floats 0–1 or integers 0–255). MeshError otherwise."""
    positions = np.asarray(vertices)
    if positions.ndim != 2 or positions.shape[1] != 3 or not len(positions):
        raise MeshError(f"vertices must be an N×3 array, got shape {positions.shape}")
    positions = np.ascontiguousarray(positions, dtype=np.float32)
    if not np.isfinite(positions).all():
        raise MeshError("vertices must be finite (a NaN or an infinity was found)")
    index = np.asarray(faces)
    if index.ndim != 2 or index.shape[1] != 3 or not len(index) or not np.issubdtype(index.dtype, np.integer):
        raise MeshError(f"faces must be an M×3 integer array, got shape {index.shape} {index.dtype}")
    low, high = int(index.min()), int(index.max())
    if low < 0 or high >= len(positions):
        raise MeshError(f"faces index vertices 0…{len(positions) - 1}, got {low}…{high}")
    shaded = None
    if normals is not None:
        shaded = np.ascontiguousarray(normals, dtype=np.float32)
        if shaded.shape != positions.shape:
            raise MeshError(f"normals must be N×3 like vertices {positions.shape}, got {shaded.shape}")
        if not np.isfinite(shaded).all():
            raise MeshError("normals must be finite (a NaN or an infinity was found)")
    return MeshArrays(positions, np.ascontiguousarray(index, dtype=np.uint32), shaded,
                      None if colors is None else rgba_bytes(colors, len(positions)))


def rgba_bytes(colors: Any, count: int) -> np.ndarray:
    """``colors`` (count×3 or count×4; floats 0–1 or integers 0–255) as (count, 4) uint8 RGBA."""
    values = np.asarray(colors)
    if values.ndim != 2 or values.shape[0] != count or values.shape[1] not in (3, 4):
        raise MeshError(f"colors must be N×3 or N×4 for {count} vertices, got shape {values.shape}")
    if np.issubdtype(values.dtype, np.floating):
        if not np.isfinite(values).all():
            raise MeshError("colors must be finite (a NaN or an infinity was found)")
        values = np.round(np.clip(values, 0.0, 1.0) * 255.0)
    rgba = np.full((count, 4), 255, dtype=np.uint8)
    rgba[:, :values.shape[1]] = np.clip(values, 0, 255).astype(np.uint8)
    return rgba


def pack_mesh(mesh: MeshArrays, **header: Any) -> bytes:
    """``mesh`` as one message; ``header``: more JSON keys (plain values)."""
    head = {**header, "vertices": len(mesh.positions), "faces": len(mesh.faces),
            "normals": mesh.normals is not None, "colors": mesh.colors is not None}
    parts = [_head(head), mesh.positions.astype("<f4", copy=False).tobytes(),
             mesh.faces.astype("<u4", copy=False).tobytes()]
    if mesh.normals is not None:
        parts.append(mesh.normals.astype("<f4", copy=False).tobytes())
    if mesh.colors is not None:
        parts.append(mesh.colors.tobytes())
    return b"".join(parts)


def with_header(data: bytes, **header: Any) -> bytes:
    """Message ``data`` (checked already) with ``header``'s keys set in its header; its arrays
    copied once, not unpacked."""
    head, offset = mesh_header(data)
    return b"".join([_head({**head, **header}), memoryview(data)[offset:]])


def _head(head: dict[str, Any]) -> bytes:
    """The magic, the header's length and the header, padded to a multiple of 4 bytes."""
    text = json.dumps(head, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    return _PREFIX.pack(MESH_MAGIC, len(text)) + text


def mesh_header(data: bytes | memoryview) -> tuple[dict[str, Any], int]:
    """A message's header and the offset of its arrays; MeshError when it is not one."""
    if len(data) < _PREFIX.size:
        raise MeshError(f"a mesh message starts with {_PREFIX.size} bytes: the magic TMSH and a header length")
    magic, length = _PREFIX.unpack_from(data)
    if magic != MESH_MAGIC:
        raise MeshError(f"a mesh message starts with TMSH, got {bytes(magic)!r}")
    if length > MAX_HEADER_BYTES or _PREFIX.size + length > len(data):
        raise MeshError(f"the mesh header's length {length} is over {MAX_HEADER_BYTES} or past the end")
    try:
        header = json.loads(bytes(data[_PREFIX.size:_PREFIX.size + length]))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MeshError(f"the mesh header is not JSON: {exc}") from None
    if not isinstance(header, dict):
        raise MeshError("the mesh header is not a JSON object")
    for key in ("vertices", "faces"):
        if type(header.get(key)) is not int or header[key] < 1:
            raise MeshError(f"the mesh header's {key!r} must be a whole number ≥ 1")
    for key in ("normals", "colors"):
        if type(header.get(key, False)) is not bool:
            raise MeshError(f"the mesh header's {key!r} must be true or false")
    return header, _PREFIX.size + length


def unpack_mesh(data: bytes | memoryview, checked: bool = True) -> tuple[dict[str, Any], MeshArrays]:
    """The header and arrays of a message of :func:`pack_mesh`, every value checked as
    :func:`checked_mesh` does (``checked`` False: only the layout, for a message from a sender that
    checked them; the arrays are views of ``data``); MeshError otherwise."""
    header, offset = mesh_header(data)
    count, faces = header["vertices"], header["faces"]
    sizes = [("positions", "<f4", (count, 3)), ("faces", "<u4", (faces, 3))]
    sizes += [("normals", "<f4", (count, 3))] if header.get("normals") else []
    sizes += [("colors", "u1", (count, 4))] if header.get("colors") else []
    expected = offset + sum(np.dtype(kind).itemsize * shape[0] * shape[1] for _, kind, shape in sizes)
    if expected != len(data):
        raise MeshError(f"the mesh message has {len(data)} bytes; its header's {count} vertices and {faces} faces "
                        f"need {expected}")
    arrays: dict[str, np.ndarray] = {}
    for name, kind, shape in sizes:
        arrays[name] = np.frombuffer(data, dtype=kind, count=shape[0] * shape[1], offset=offset).reshape(shape)
        offset += arrays[name].nbytes
    positions, index = arrays["positions"], arrays["faces"]
    mesh = MeshArrays(positions, index, arrays.get("normals"), arrays.get("colors"))
    if not checked:
        return header, mesh
    if not np.isfinite(positions).all():
        raise MeshError("vertices must be finite (a NaN or an infinity was found)")
    if int(index.max()) >= count:
        raise MeshError(f"faces index vertices 0…{count - 1}, got up to {int(index.max())}")
    if mesh.normals is not None and not np.isfinite(mesh.normals).all():
        raise MeshError("normals must be finite (a NaN or an infinity was found)")
    return header, mesh


def is_mesh_spec(spec: str | None) -> TypeGuard[str]:
    """Whether scene ``spec`` is a mesh sent as arrays."""
    return spec is not None and spec.startswith(MESH_PREFIX)


def mesh_group(spec: str) -> str:
    """``mesh:GROUP:STEP`` → ``GROUP``."""
    return spec[len(MESH_PREFIX):].rsplit(":", 1)[0]
