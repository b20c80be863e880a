"""The GPU-ready form of a scene's geometry (issue 31): one interleaved vertex array and one index
array, in the layout the renderer's vertex buffer has and the scene cache stores as it is. No GL here.

A vertex is its position (3 float32), its normal (3 float16 and 2 bytes of padding: 5·10⁻⁴ at
worst, a 0.03° turn, far below what 8-bit shading shows) and, only when some batch of the scene has
them, texture coordinates (2 float32) and a colour (4 float32, linear): 20 bytes a vertex for a
scan, where float32 normals and stand-in uvs and colours took 48. Indices are uint32, 3 a
triangle; each batch's are its own (0 is its first vertex) and :func:`gpu_indices` adds the
batch's first vertex for the one index buffer every batch is drawn from.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from node.scene import compiled
from node.scene.face_pass import for_blocks
from node.scene.mesh import MeshBatch

#: Bytes of indices converted at a time when batches are made one buffer.
INDEX_BLOCK = 1 << 22


@dataclass(frozen=True, slots=True)
class VertexLayout:
    """Which optional attributes the interleaved vertices carry: texture coordinates (``uvs``) and
    colours (``colors``); position and normal are always there."""

    uvs: bool = False
    colors: bool = False

    @classmethod
    def of(cls, batches: Sequence[MeshBatch]) -> VertexLayout:
        """The layout that holds every attribute some of ``batches`` has."""
        return cls(any(b.uvs is not None for b in batches), any(b.colors is not None for b in batches))

    @property
    def dtype(self) -> np.dtype:
        """The structured dtype of one vertex."""
        fields: list[tuple[str, str, tuple[int, ...]] | tuple[str, str]] = [
            ("position", "<f4", (3,)), ("normal", "<f2", (3,)), ("pad", "<u2")]
        if self.uvs:
            fields.append(("uv", "<f4", (2,)))
        if self.colors:
            fields.append(("color", "<f4", (4,)))
        return np.dtype(fields)

    @property
    def stride(self) -> int:
        """Bytes per vertex."""
        return self.dtype.itemsize

    @property
    def gl_format(self) -> str:
        """The moderngl buffer format of :attr:`attributes`."""
        return "3f 3f2 2x" + (" 2f" if self.uvs else "") + (" 4f" if self.colors else "")

    @property
    def attributes(self) -> tuple[str, ...]:
        """The vertex shader inputs the format feeds, in order."""
        return ("in_position", "in_normal") + (("in_uv",) if self.uvs else ()) + (("in_color",) if self.colors else ())

    def to_json(self) -> dict[str, bool]:
        return {"uvs": self.uvs, "colors": self.colors}


@dataclass(frozen=True, eq=False)
class PackedGeometry:
    """A scene's geometry as the GPU takes it: ``vertices`` (V,) of ``layout.dtype`` (every batch's
    vertices in batch order), ``indices`` (3F,) uint32, each batch's numbering its own vertices from
    0, and ``vertex_bounds`` (B + 1,) int64: batch b's vertices are [vertex_bounds[b],
    vertex_bounds[b + 1])."""

    layout: VertexLayout
    vertices: np.ndarray
    indices: np.ndarray
    vertex_bounds: np.ndarray

    @property
    def nbytes(self) -> int:
        return int(self.vertices.nbytes + self.indices.nbytes)


def pack_vertices(batches: Sequence[MeshBatch], layout: VertexLayout | None = None) -> np.ndarray:
    """(V,) vertices of ``layout`` (default :meth:`VertexLayout.of` the batches) of all ``batches``
    in order: uvs absent from a batch are zeros, colours ones. Every batch needs its normals."""
    layout = layout or VertexLayout.of(batches)
    out = np.zeros(sum(b.vertex_count for b in batches), layout.dtype)
    first = 0
    for batch in batches:
        assert batch.normals is not None, "normals are computed before packing"

        fast = compiled.available(batch.vertex_count) and batch.normals.dtype == np.float32

        def fill(start: int, end: int, batch: MeshBatch = batch, offset: int = first, fast: bool = fast) -> None:
            rows = out[offset + start:offset + end]
            if fast:
                compiled.interleave(batch.positions[start:end], batch.normals[start:end], rows)
            else:
                rows["position"] = batch.positions[start:end]
                rows["normal"] = batch.normals[start:end]
            if layout.uvs and batch.uvs is not None:
                rows["uv"] = batch.uvs[start:end]
            if layout.colors:
                rows["color"] = 1.0 if batch.colors is None else batch.colors[start:end]

        for_blocks(batch.vertex_count, fill)
        first += batch.vertex_count
    return out


def vertex_extras(batches: Sequence[MeshBatch]) -> np.ndarray | None:
    """(V, 6) float32 rows of tangent and second uv for all ``batches``' vertices in order (zeros
    where a batch has none: a zero tangent makes the shader derive the frame), or None when no
    batch has either."""
    if all(batch.tangents is None and batch.uvs1 is None for batch in batches):
        return None
    parts = []
    for batch in batches:
        count = batch.vertex_count
        tangents = batch.tangents if batch.tangents is not None else np.zeros((count, 4), np.float32)
        uvs1 = batch.uvs1 if batch.uvs1 is not None else np.zeros((count, 2), np.float32)
        parts.append(np.concatenate([tangents, uvs1], axis=1, dtype=np.float32))
    return np.concatenate(parts)


def pack(batches: Sequence[MeshBatch]) -> PackedGeometry:
    """The :class:`PackedGeometry` of ``batches``."""
    counts = np.array([b.vertex_count for b in batches], np.int64)
    parts = [np.asarray(b.faces, np.uint32).reshape(-1) for b in batches]
    indices = parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.zeros(0, np.uint32)
    layout = VertexLayout.of(batches)
    return PackedGeometry(layout, pack_vertices(batches, layout), indices, np.concatenate(([0], np.cumsum(counts))))


def gpu_indices(indices: np.ndarray, index_bounds: np.ndarray, vertex_bounds: np.ndarray, first: int, end: int,
                out: np.ndarray | None = None) -> np.ndarray:
    """Indices [``first``, ``end``) of ``indices`` (batch-local, batch b's at [index_bounds[b],
    index_bounds[b + 1])) with each one's batch's first vertex (``vertex_bounds``) added: a piece of
    the one index buffer (uint32); written into ``out`` when given."""
    piece = np.asarray(indices[first:end])
    out = np.empty(end - first, np.uint32) if out is None else out[:end - first]
    lo = int(np.searchsorted(index_bounds, first, side="right")) - 1
    hi = int(np.searchsorted(index_bounds, end, side="left"))
    for batch in range(max(lo, 0), hi):
        a = max(int(index_bounds[batch]), first) - first
        b = min(int(index_bounds[batch + 1]), end) - first
        np.add(piece[a:b], np.uint32(vertex_bounds[batch]), out=out[a:b])
    return out
