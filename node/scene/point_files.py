"""Point cloud files read as arrays (issue 36): LAS and LAZ by laspy with the lazrs backend (LAZ
decoded in parallel, the maintained Rust port of LASzip that laspy's authors keep; PDAL is not on
PyPI and laszip-python decodes no faster), and PLY files whose vertices have no faces (binary of
either byte order read by ``numpy.frombuffer`` over a memory map of the file's own layout, ASCII by
``numpy.loadtxt``). No GL here.

What a reader gives (:class:`PointArrays`): positions in float64 world coordinates (survey
coordinates of 10⁶ m keep their millimetres), and what the points carry — RGB, intensity, normals
(kept for a later shading; EDL does not need them).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from node.scene.mesh import SceneError
from node.scene.ply import PLY_TYPES, _colors, _header

#: Points a LAS/LAZ file is read by at a time.
LAS_CHUNK = 4_000_000
#: Point cloud file suffixes (PLY files are point clouds when they have no faces: :func:`is_point_ply`).
LAS_SUFFIXES = (".las", ".laz")


@dataclass(frozen=True, eq=False)
class PointArrays:
    """N points: ``positions`` (N, 3) float64 world, ``colors`` (N, 3) uint8 sRGB or None,
    ``intensity`` (N,) float32 or None, ``normals`` (N, 3) float32 or None."""

    positions: np.ndarray
    colors: np.ndarray | None = None
    intensity: np.ndarray | None = None
    normals: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(self.positions.shape[0])


def is_point_file(path: Path) -> bool:
    """Whether the file at ``path`` is a point cloud: LAS/LAZ, or a PLY with vertices and no faces."""
    suffix = path.suffix.lower()
    if suffix in LAS_SUFFIXES:
        return True
    return suffix == ".ply" and is_point_ply(path)


def is_point_ply(path: Path) -> bool:
    """Whether the PLY at ``path`` has vertices with x, y, z and no faces (False when unreadable:
    the mesh reader then says why)."""
    try:
        with path.open("rb") as file:
            head = np.frombuffer(file.read(1 << 16), np.uint8)
        _, elements, _ = _header(head, path)
    except (OSError, SceneError):
        return False
    counts = {element.name: element.count for element in elements}
    vertex = next((element for element in elements if element.name == "vertex"), None)
    return vertex is not None and vertex.count > 0 and counts.get("face", 0) == 0 and \
        {"x", "y", "z"} <= {name for name, _ in vertex.scalars}


def read_points(path: Path) -> PointArrays:
    """The points of the LAS, LAZ or PLY file at ``path``; raises SceneError naming the file and why."""
    if path.suffix.lower() in LAS_SUFFIXES:
        return read_las(path)
    return read_point_ply(path)


def read_las(path: Path) -> PointArrays:
    """A LAS/LAZ file's points, colours (16-bit RGB scaled to 8 bits) and intensities, read
    :data:`LAS_CHUNK` points at a time into arrays of the file's count (its point records, 20–67
    bytes each, are never all in memory)."""
    import laspy

    try:
        with laspy.open(str(path), laz_backend=laspy.LazBackend.LazrsParallel) as reader:
            header = reader.header
            count = int(header.point_count)
            if count == 0:
                raise SceneError(f"{path}: no points")
            names = set(header.point_format.dimension_names)
            scales, offsets = np.asarray(header.scales, np.float64), np.asarray(header.offsets, np.float64)
            positions = np.empty((count, 3), np.float64)
            colors = np.empty((count, 3), np.uint16) if {"red", "green", "blue"} <= names else None
            intensity = np.empty(count, np.float32) if "intensity" in names else None
            done = 0
            for chunk in reader.chunk_iterator(LAS_CHUNK):
                end = done + len(chunk)
                if end > count:
                    raise SceneError(f"{path}: more points than its header's {count}")
                for axis, name in enumerate(("X", "Y", "Z")):
                    column = positions[done:end, axis]
                    np.multiply(chunk.array[name], scales[axis], out=column, casting="unsafe")
                    column += offsets[axis]
                if colors is not None:
                    for column, name in enumerate(("red", "green", "blue")):
                        colors[done:end, column] = chunk[name]
                if intensity is not None:
                    intensity[done:end] = chunk["intensity"]
                done = end
    except (laspy.LaspyException, OSError, ValueError, RuntimeError) as exc:
        raise SceneError(f"{path}: corrupt or unreadable {path.suffix[1:].upper()} "
                         f"({' '.join(str(exc).split())[:200]})") from None
    if done < count:
        raise SceneError(f"{path}: corrupt or unreadable {path.suffix[1:].upper()} (truncated: {done} of its "
                         f"header's {count} points)")
    rgb = None if colors is None else (colors >> 8 if colors.max(initial=0) > 255 else colors).astype(np.uint8)
    return PointArrays(positions, rgb, intensity)


def read_point_ply(path: Path) -> PointArrays:
    """A PLY file's vertices (x, y, z; red, green, blue; intensity or scalar_intensity; nx, ny, nz)."""
    try:
        data = np.memmap(path, dtype=np.uint8, mode="r")
    except (ValueError, OSError) as exc:
        raise SceneError(f"{path}: corrupt or unreadable PLY ({exc})") from None
    fmt, elements, offset = _header(data, path)
    if not elements or elements[0].name != "vertex" or elements[0].lists:
        raise SceneError(f"{path}: a point cloud PLY has its vertex element first, of scalar properties")
    vertex = elements[0]
    if any(kind not in PLY_TYPES for _, kind in vertex.scalars):
        raise SceneError(f"{path}: corrupt or unreadable PLY (unknown property type)")
    names = {name for name, _ in vertex.scalars}
    if not {"x", "y", "z"} <= names:
        raise SceneError(f"{path}: corrupt or unreadable PLY (its vertices have no x, y, z)")
    if fmt in ("binary_little_endian", "binary_big_endian"):
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, np.dtype(PLY_TYPES[kind]).newbyteorder(order)) for name, kind in vertex.scalars])
        if len(data) < offset + vertex.count * dtype.itemsize:
            raise SceneError(f"{path}: corrupt or unreadable PLY (truncated: {len(data)} bytes, its header needs "
                             f"{offset + vertex.count * dtype.itemsize})")
        rows = np.frombuffer(data, dtype, vertex.count, offset)
    elif fmt == "ascii":
        rows = _ascii_rows(data, offset, vertex.count, [(name, PLY_TYPES[kind]) for name, kind in vertex.scalars],
                           path)
    else:
        raise SceneError(f"{path}: corrupt or unreadable PLY (format {fmt!r})")
    if vertex.count == 0:
        raise SceneError(f"{path}: no points")
    positions = np.stack([np.asarray(rows[axis], np.float64) for axis in ("x", "y", "z")], axis=1)
    intensity_name = next((name for name in ("intensity", "scalar_intensity") if name in names), None)
    return PointArrays(
        positions, _colors(rows, names),
        None if intensity_name is None else np.asarray(rows[intensity_name], np.float32),
        np.stack([np.asarray(rows[n], np.float32) for n in ("nx", "ny", "nz")], axis=1)
        if {"nx", "ny", "nz"} <= names else None)


def _ascii_rows(data: np.ndarray, offset: int, count: int, fields: list[tuple[str, str]], path: Path) -> np.ndarray:
    """The first ``count`` lines of an ASCII PLY's body as a structured array of ``fields``."""
    dtype = np.dtype([(name, kind.lstrip("<>")) for name, kind in fields])
    lines = bytes(data[offset:]).decode("ascii", "replace").splitlines()[:count]
    if len(lines) < count:
        raise SceneError(f"{path}: corrupt or unreadable PLY (truncated: {len(lines)} of {count} vertices)")
    try:
        values = np.loadtxt(lines, dtype=np.float64, ndmin=2, usecols=range(len(fields)))
    except ValueError as exc:
        raise SceneError(f"{path}: corrupt or unreadable PLY ({exc})") from None
    rows = np.empty(count, dtype)
    for column, (name, _) in enumerate(fields):
        rows[name] = values[:, column]
    return rows
