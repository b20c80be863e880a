"""PLY files read as arrays (issue 31: a scan of tens of millions of triangles in a second, not a
row at a time): :func:`read_ply`.

A binary little-endian PLY whose vertex element has only scalar properties and whose faces are
one list of exactly three indices each (what scanners and most converters write) is read by
``numpy.frombuffer`` over a memory map of the file's own layout: no parse, one copy of the columns
it keeps. Anything else (ASCII, big-endian, polygons, other list layouts) is read by pyminiply
(miniply, compiled), which triangulates polygons. No GL here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from node.scene import compiled
from node.scene.face_pass import for_blocks
from node.scene.mesh import SceneError

#: PLY scalar type names and their numpy little-endian types.
PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "<i2", "int16": "<i2",
             "ushort": "<u2", "uint16": "<u2", "int": "<i4", "int32": "<i4", "uint": "<u4", "uint32": "<u4",
             "float": "<f4", "float32": "<f4", "double": "<f8", "float64": "<f8"}
#: Most header bytes read before ``end_header`` must have appeared.
MAX_HEADER_BYTES = 1 << 16
#: Texture coordinate property names, in the order tried.
UV_NAMES = (("s", "t"), ("u", "v"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


@dataclass(frozen=True, eq=False)
class PlyMesh:
    """A PLY file's triangles: ``vertices`` (V, 3) float32, ``faces`` (F, 3) uint32, and what its
    vertices carry: ``normals`` (V, 3) float32, ``uvs`` (V, 2) float32 (as stored), ``colors`` (V, 3|4)
    uint8 sRGB, each None when absent."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray | None = None
    uvs: np.ndarray | None = None
    colors: np.ndarray | None = None


@dataclass(frozen=True, slots=True)
class _Element:
    name: str
    count: int
    scalars: tuple[tuple[str, str], ...]       # (name, PLY type) of scalar properties, in order
    lists: tuple[tuple[str, str, str], ...]    # (name, count type, item type) of list properties


def _header(data: np.ndarray, path: Path) -> tuple[str, list[_Element], int]:
    """(format, elements, offset of the body) of the PLY in ``data``; raises SceneError."""
    end = bytes(data[:MAX_HEADER_BYTES]).find(b"end_header")
    if not bytes(data[:3]) == b"ply" or end < 0:
        raise SceneError(f"{path}: corrupt or unreadable PLY (no 'ply' magic or no end_header)")
    body = end + len(b"end_header")
    while body < len(data) and bytes(data[body:body + 1]) in (b"\r", b"\n"):
        body += 1
        if bytes(data[body - 1:body]) == b"\n":
            break
    fmt, elements = "", []
    for line in bytes(data[:end]).decode("ascii", "replace").splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] == "format" and len(words) >= 2:
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append(_Element(words[1], int(words[2]), (), ()))
        elif words[0] == "property" and elements:
            last = elements[-1]
            if len(words) == 5 and words[1] == "list":
                lists = (*last.lists, (words[4], words[2], words[3]))
                elements[-1] = _Element(last.name, last.count, last.scalars, lists)
            elif len(words) == 3:
                elements[-1] = _Element(last.name, last.count, (*last.scalars, (words[2], words[1])), last.lists)
    return fmt, elements, body


def read_ply(path: Path) -> PlyMesh:
    """The triangles of the PLY file at ``path``; raises SceneError naming the file and the reason."""
    try:
        data = np.memmap(path, dtype=np.uint8, mode="r")
    except ValueError as exc:        # an empty file
        raise SceneError(f"{path}: corrupt or unreadable PLY ({exc})") from None
    except OSError as exc:
        raise SceneError(f"{path}: unreadable ({exc.strerror or exc})") from None
    fast = _read_fixed_layout(data, path)
    return fast if fast is not None else _read_with_miniply(path)


def read_ply_arrays(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float32, faces (F, 3) uint32) of the PLY at ``path``."""
    mesh = read_ply(path)
    return mesh.vertices, mesh.faces


def _read_fixed_layout(data: np.ndarray, path: Path) -> PlyMesh | None:
    """The mesh when the file is binary little-endian with scalar vertices followed by faces of one
    list of three indices each; None when it is laid out otherwise. Raises SceneError when it is
    that layout but truncated or its indices are out of range."""
    fmt, elements, offset = _header(data, path)
    if fmt != "binary_little_endian" or len(elements) < 2:
        return None
    vertex, face = elements[0], elements[1]
    if vertex.name != "vertex" or vertex.lists or face.name != "face" or face.scalars or len(face.lists) != 1:
        return None
    _, count_type, item_type = face.lists[0]
    if count_type not in PLY_TYPES or item_type not in PLY_TYPES or np.dtype(PLY_TYPES[item_type]).kind not in "iu":
        return None
    if any(kind not in PLY_TYPES for _, kind in vertex.scalars):
        return None
    vertex_type = np.dtype([(name, PLY_TYPES[kind]) for name, kind in vertex.scalars])
    face_type = np.dtype([("n", PLY_TYPES[count_type]), ("v", PLY_TYPES[item_type], (3,))])
    needed = offset + vertex.count * vertex_type.itemsize + face.count * face_type.itemsize
    if len(data) < needed:
        raise SceneError(f"{path}: corrupt or unreadable PLY (truncated: {len(data)} bytes, its header needs {needed})")
    rows = np.frombuffer(data, vertex_type, vertex.count, offset)
    names = set(vertex_type.names or ())
    if not {"x", "y", "z"} <= names:
        raise SceneError(f"{path}: corrupt or unreadable PLY (its vertices have no x, y, z)")
    faces = _faces(np.frombuffer(data, face_type, face.count, offset + vertex.count * vertex_type.itemsize),
                   vertex.count, path)
    if faces is None:
        return None
    return PlyMesh(
        vertices=_columns(rows, ("x", "y", "z"), np.float32),
        faces=faces,
        normals=_columns(rows, ("nx", "ny", "nz"), np.float32) if {"nx", "ny", "nz"} <= names else None,
        uvs=next((_columns(rows, pair, np.float32) for pair in UV_NAMES if set(pair) <= names), None),
        colors=_colors(rows, names),
    )


def _faces(records: np.ndarray, vertex_count: int, path: Path) -> np.ndarray | None:
    """(F, 3) uint32 indices of the face ``records`` (a count and three indices each), copied a
    block at a time on every core; None when some face is not a triangle. Raises SceneError when an
    index is out of range (a negative one wraps to a large one in the copy)."""
    if records.dtype.itemsize == 13 and records.dtype["v"].itemsize == 12 and records.flags.c_contiguous \
            and compiled.available(len(records)):
        out, all_triangles, most = compiled.face_records(records)
        if not all_triangles:
            return None
        if most >= vertex_count:
            raise SceneError(f"{path}: face indices out of range (0..{vertex_count - 1})")
        return out
    out = np.empty((len(records), 3), np.uint32)
    triangles, largest = [True], [0]

    def block(first: int, end: int) -> None:
        piece = records[first:end]
        triangles.append(bool((piece["n"] == 3).all()))
        out[first:end] = piece["v"]
        largest.append(int(out[first:end].max()))

    for_blocks(len(records), block, 1 << 20)
    if not all(triangles):
        return None
    if len(records) and max(largest) >= vertex_count:
        raise SceneError(f"{path}: face indices out of range (0..{vertex_count - 1})")
    return out


def _columns(rows: np.ndarray, names: tuple[str, ...], dtype: type) -> np.ndarray:
    """(N, len(names)) ``dtype`` of the named fields of structured ``rows``: one copy (a block at a
    time on threads) when they are all its fields, in that order, of that type."""
    if rows.dtype.names == names and all(rows.dtype[name] == np.dtype(dtype) for name in names):
        source = rows.view(np.dtype(dtype)).reshape(len(rows), len(names))
        copied = np.empty(source.shape, source.dtype)

        def copy(first: int, end: int) -> None:
            copied[first:end] = source[first:end]

        for_blocks(len(rows), copy, 1 << 20)
        return copied
    out = np.empty((len(rows), len(names)), dtype)
    for column, name in enumerate(names):
        out[:, column] = rows[name]
    return out


def _colors(rows: np.ndarray, names: set[str]) -> np.ndarray | None:
    """(N, 3|4) uint8 sRGB vertex colours (red, green, blue[, alpha]; floats in 0..1 scaled), or None."""
    channels = [name for name in ("red", "green", "blue", "alpha") if name in names]
    if channels[:3] != ["red", "green", "blue"]:
        return None
    values = _columns(rows, tuple(channels), np.float64)
    if rows.dtype["red"].kind == "f":
        values = values * 255.0
    elif rows.dtype["red"].itemsize > 1:
        values = values / np.iinfo(rows.dtype["red"]).max * 255.0
    return np.clip(np.rint(values), 0, 255).astype(np.uint8)


def _read_with_miniply(path: Path) -> PlyMesh:
    """Any other PLY, by pyminiply (polygons triangulated)."""
    import pyminiply

    try:
        vertices, faces, normals, uvs, colors = pyminiply.read(str(path))
        faces = np.asarray(faces).reshape(-1, 3)
        vertices = np.asarray(vertices, np.float32).reshape(-1, 3)
    except (RuntimeError, ValueError, OSError) as exc:
        raise SceneError(f"{path}: corrupt or unreadable PLY ({' '.join(str(exc).split())})") from None
    if len(faces) and (int(faces.min()) < 0 or int(faces.max()) >= len(vertices)):
        raise SceneError(f"{path}: face indices out of range (0..{len(vertices) - 1})")
    return PlyMesh(
        vertices=np.ascontiguousarray(vertices, np.float32),
        faces=faces.astype(np.uint32),
        normals=np.ascontiguousarray(normals, np.float32) if len(normals) == len(vertices) and len(vertices) else None,
        uvs=np.ascontiguousarray(uvs, np.float32) if len(uvs) == len(vertices) and len(vertices) else None,
        colors=np.ascontiguousarray(colors, np.uint8) if len(colors) == len(vertices) and len(vertices) else None,
    )
