"""The glTF 2.0 container and its accessors, as numpy (glTF 2.0 §3.6 buffers, buffer views and
accessors, including sparse accessors; §4.4 the GLB container), for the parts trimesh does not
hand over: the node hierarchy and the animations (:mod:`tessera.scene.animation`).

Sans-I/O: :func:`read_document` takes the file's bytes and a ``read_uri(uri) -> bytes`` callback
for external buffers (``data:`` URIs are decoded here); it never opens a file itself. Given a GLB
as a memory map (or any buffer but ``bytes``), its BIN chunk is a view of it, not a copy: a big
model's buffer is read only where an accessor is.
"""

from __future__ import annotations

import base64
import binascii
import json
import mmap
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

GLB_MAGIC = b"glTF"
GLB_JSON = 0x4E4F534A
GLB_BIN = 0x004E4942
#: componentType → little-endian numpy dtype (§3.6.2.2).
COMPONENT_TYPES = {5120: "<i1", 5121: "<u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
#: accessor type → components (the vector types only: matrices are not needed here).
COMPONENT_COUNTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
#: Normalised integer componentType → divisor (§3.11: signed values clamp at −1).
NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}


class GltfError(ValueError):
    """A glTF file that cannot be read; the message says what is wrong."""


@dataclass(frozen=True, eq=False)
class GltfDocument:
    """A glTF file's JSON and its buffers' bytes (``buffers[i]`` for ``json["buffers"][i]``)."""

    json: dict[str, Any]
    buffers: tuple[bytes | memoryview, ...]

    def accessor(self, index: object) -> np.ndarray:
        """Accessor ``index`` as a (count, components) array: float64 for float and normalised
        components, int64 otherwise. Raises GltfError."""
        accessors = self.json.get("accessors", [])
        if not isinstance(index, int) or not 0 <= index < len(accessors):
            raise GltfError(f"accessor {index!r} does not exist")
        spec = accessors[index]
        where = f"accessor {index}"
        try:
            component, kind, count = spec["componentType"], spec["type"], spec["count"]
        except (KeyError, TypeError):
            raise GltfError(f"{where} lacks componentType, type or count") from None
        if component not in COMPONENT_TYPES or kind not in COMPONENT_COUNTS:
            raise GltfError(f"{where}: unsupported {kind} of componentType {component}")
        if not isinstance(count, int) or count < 1:
            raise GltfError(f"{where}: count must be >= 1, got {count!r}")
        width = COMPONENT_COUNTS[kind]
        if "bufferView" in spec:
            values = self._view_array(spec["bufferView"], spec.get("byteOffset", 0), component, count, width, where)
        else:
            values = np.zeros((count, width), COMPONENT_TYPES[component])
        sparse = spec.get("sparse")
        if sparse is not None:
            values = self._apply_sparse(values, sparse, component, width, where)
        if component == 5126:
            return values.astype(np.float64)
        if spec.get("normalized", False):
            return np.maximum(values.astype(np.float64) / NORMALIZE[component], -1.0)
        return values.astype(np.int64)

    def _view_array(self, view_index: Any, offset: Any, component: int, count: int, width: int,
                    where: str, packed: bool = False) -> np.ndarray:
        """``count`` elements of ``width`` components from buffer view ``view_index`` at ``offset``
        (the view's byteStride applies unless ``packed``): a (count, width) copy."""
        views = self.json.get("bufferViews", [])
        if not isinstance(view_index, int) or not 0 <= view_index < len(views):
            raise GltfError(f"{where}: buffer view {view_index!r} does not exist")
        view = views[view_index]
        buffer_index = view.get("buffer")
        if not isinstance(buffer_index, int) or not 0 <= buffer_index < len(self.buffers):
            raise GltfError(f"{where}: buffer {buffer_index!r} does not exist")
        buffer = self.buffers[buffer_index]
        dtype = np.dtype(COMPONENT_TYPES[component])
        element = dtype.itemsize * width
        stride = element if packed else view.get("byteStride") or element
        start = view.get("byteOffset", 0) + offset
        length = view.get("byteLength", 0)
        needed = offset + stride * (count - 1) + element
        if not all(isinstance(v, int) and v >= 0 for v in (start, length, stride)) or stride < element:
            raise GltfError(f"{where}: bad byteOffset, byteLength or byteStride")
        if needed > length or view.get("byteOffset", 0) + length > len(buffer):
            raise GltfError(f"{where}: reads past the end of its buffer view or buffer")
        array = np.ndarray((count, width), dtype, buffer=buffer, offset=start, strides=(stride, dtype.itemsize))
        return array.copy()

    def _apply_sparse(self, values: np.ndarray, sparse: Any, component: int, width: int, where: str) -> np.ndarray:
        try:
            count, indices, replacements = sparse["count"], sparse["indices"], sparse["values"]
            index_type = indices["componentType"]
        except (KeyError, TypeError):
            raise GltfError(f"{where}: sparse lacks count, indices or values") from None
        if index_type not in (5121, 5123, 5125) or not isinstance(count, int) or count < 1:
            raise GltfError(f"{where}: bad sparse indices")
        rows = self._view_array(indices.get("bufferView"), indices.get("byteOffset", 0), index_type, count, 1,
                                f"{where} sparse indices", packed=True)[:, 0].astype(np.int64)
        if rows.max() >= len(values):
            raise GltfError(f"{where}: sparse index out of range")
        new = self._view_array(replacements.get("bufferView"), replacements.get("byteOffset", 0), component,
                               count, width, f"{where} sparse values", packed=True)
        values = values.copy()
        values[rows] = new
        return values


def read_glb(data: bytes | mmap.mmap) -> tuple[dict[str, Any], bytes | memoryview | None]:
    """The JSON chunk and the BIN chunk (None if absent) of a GLB file's bytes (§4.4): a slice of
    ``bytes``, else a view of ``data`` (no copy)."""
    if len(data) < 20 or data[:4] != GLB_MAGIC:
        raise GltfError("not a GLB file (no glTF magic)")
    version, length = struct.unpack_from("<II", data, 4)
    if version != 2:
        raise GltfError(f"GLB version {version}; only 2 is supported")
    if length > len(data):
        raise GltfError(f"GLB is truncated: {len(data)} of {length} bytes")
    chunks: list[tuple[int, int, int]] = []   # (kind, first byte, end byte)
    offset = 12
    while offset + 8 <= length:
        size, kind = struct.unpack_from("<II", data, offset)
        if offset + 8 + size > length:
            raise GltfError("GLB chunk runs past the end of the file")
        chunks.append((kind, offset + 8, offset + 8 + size))
        offset += 8 + size + (-size % 4)
    if not chunks or chunks[0][0] != GLB_JSON:
        raise GltfError("GLB does not start with a JSON chunk")
    binary: bytes | memoryview | None = None
    if len(chunks) > 1 and chunks[1][0] == GLB_BIN:
        first, end = chunks[1][1], chunks[1][2]
        binary = data[first:end] if isinstance(data, bytes) else memoryview(data)[first:end]
    return parse_json(bytes(data[chunks[0][1]:chunks[0][2]])), binary


def parse_json(data: bytes) -> dict[str, Any]:
    """A glTF's JSON object from its bytes; GltfError for invalid JSON or JSON that is not an object."""
    try:
        document = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise GltfError(f"invalid glTF JSON ({exc})") from None
    if not isinstance(document, dict):
        raise GltfError("glTF JSON is not an object")
    return document


def read_document(data: bytes | mmap.mmap, read_uri: Callable[[str], bytes]) -> GltfDocument:
    """A .gltf (JSON) or .glb file's bytes, with every buffer loaded: the GLB's own BIN chunk,
    ``data:`` URIs decoded, other URIs through ``read_uri`` (relative to the file; its errors
    propagate)."""
    if data[:4] == GLB_MAGIC:
        document, binary = read_glb(data)
    else:
        document, binary = parse_json(bytes(data)), None
    buffers: list[bytes | memoryview] = []
    specs: Sequence[Any] = document.get("buffers", [])
    for number, spec in enumerate(specs):
        uri = spec.get("uri") if isinstance(spec, dict) else None
        if uri is None:
            if number != 0 or binary is None:
                raise GltfError(f"buffer {number} has no uri and no GLB BIN chunk")
            buffers.append(binary)
        elif uri.startswith("data:"):
            buffers.append(_data_uri(uri, number))
        else:
            buffers.append(read_uri(uri))
    return GltfDocument(document, tuple(buffers))


def _data_uri(uri: str, number: int) -> bytes:
    header, _, payload = uri.partition(",")
    if not header.endswith(";base64"):
        raise GltfError(f"buffer {number}: only base64 data URIs are supported")
    try:
        return base64.b64decode(payload, validate=True)
    except (binascii.Error, ValueError):
        raise GltfError(f"buffer {number}: invalid base64 data URI") from None
