"""A loaded scene (:class:`SceneData`): batches in draw order, split into octree chunks at load
(seed 002 §3.4, :mod:`node.scene.chunks`), with the bounds and primitive groups a node reports,
its named objects (:class:`tessera.scene.graph.ObjectGraph`, issue 11: each batch belongs to one)
and its animations (:mod:`tessera.scene.animation`). No GL here."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from node.scene.chunks import PrimitiveGroups, SceneChunks, Splitter, octree_chunks, split_batches
from node.scene.mesh import MeshBatch, SceneError
from node.scene.octree import DEFAULT_FACE_LIMIT
from node.scene.packing import PackedGeometry, VertexLayout
from node.scene.pages import is_mapped
from tessera.scene.animation import Animation, sample_animations
from tessera.scene.graph import ObjectGraph, SceneObject
from tessera.scene.state import ObjectPatch, SceneState, SceneStateError


@dataclass(frozen=True, eq=False)
class SceneData:
    """A loaded scene: batches in draw order (opaque first), world ``bounds`` (2, 3) float64 at the
    base pose, its ``chunks`` (batches over the face limit are split; their faces are in chunk
    order), the primitive ``groups`` sent to the coordinator (chunk boxes and triangle counts), its
    ``objects`` (each batch's ``owner`` indexes them; their bounds and triangles are the batches')
    and its ``animations``."""

    name: str
    batches: tuple[MeshBatch, ...]
    bounds: np.ndarray
    triangle_count: int
    groups: PrimitiveGroups
    chunks: SceneChunks
    objects: ObjectGraph
    animations: tuple[Animation, ...] = ()
    #: The batches' geometry as the GPU takes it, when it is at hand already (mapped from a scene
    #: cache, :mod:`node.scene.cache`; the batches' arrays are views of it); None: packed on upload.
    geometry: PackedGeometry | None = None

    @classmethod
    def from_batches(cls, name: str, batches: list[MeshBatch], face_limit: int = DEFAULT_FACE_LIMIT,
                     objects: Sequence[SceneObject] | None = None, animations: Sequence[Animation] = (),
                     splitter: Splitter = octree_chunks) -> SceneData:
        """Drop empty batches, order blended ones last, split (by octree: ``splitter``), compute
        bounds and groups. ``objects`` (their bounds and triangles are filled in here) default to one
        per batch, named after it, each batch its owner."""
        if objects is None:
            objects = _one_object_per_batch(batches)
            batches = [dataclasses.replace(b, owner=number) for number, b in enumerate(batches)]
        if any(not 0 <= b.owner < len(objects) for b in batches):
            raise SceneError(f"{name}: a mesh belongs to no object")
        kept = [b for b in batches if b.triangle_count > 0]
        if not kept:
            raise SceneError(f"{name}: no triangles")
        kept.sort(key=lambda b: b.alpha_mode == "BLEND")
        split, chunks = split_batches(kept, face_limit, splitter)
        # A batch's box is its chunks' (each tight over its faces' corners).
        lo = np.minimum.reduceat(chunks.boxes[:, 0], chunks.batch_bounds[:-1], axis=0)
        hi = np.maximum.reduceat(chunks.boxes[:, 1], chunks.batch_bounds[:-1], axis=0)
        boxes = np.stack([lo, hi], axis=1).astype(np.float64)
        bounds = np.stack([boxes[:, 0].min(axis=0), boxes[:, 1].max(axis=0)])
        triangles = sum(b.triangle_count for b in split)
        try:
            graph = ObjectGraph(_measured(objects, split, boxes))
        except SceneStateError as exc:
            raise SceneError(f"{name}: {exc}") from None
        groups = chunks.primitive_groups(np.array([b.owner for b in split], np.int64))
        return cls(name, tuple(split), bounds, triangles, groups, chunks, graph, tuple(animations))

    def with_face_limit(self, face_limit: int) -> SceneData:
        """The same scene split with another face limit (itself when the limit is the same)."""
        if face_limit == self.chunks.face_limit:
            return self
        return SceneData.from_batches(self.name, list(self.batches), face_limit, self.objects.objects, self.animations)

    @property
    def vertex_count(self) -> int:
        return sum(b.vertex_count for b in self.batches)

    @property
    def gpu_bytes(self) -> int:
        """Bytes of its vertex and index buffers as :func:`node.scene.packing.pack` lays them out
        (what the GPU holds of it; on llvmpipe, host memory)."""
        if self.geometry is not None:
            return self.geometry.nbytes
        stride = VertexLayout.of(self.batches).stride
        return sum(b.vertex_count for b in self.batches) * stride + 12 * self.triangle_count

    @property
    def nbytes(self) -> int:
        """Bytes of its batches' arrays held in memory (positions, normals, faces, uvs, colours,
        textures, tangents, second uvs), an array batches share (a texture) once; arrays mapped from a
        file (a scene cache's) are not counted: their pages leave once uploaded."""
        arrays = {id(a): a for b in self.batches
                  for a in (b.positions, b.normals, b.faces, b.uvs, b.colors, b.texture, b.tangents, b.uvs1)
                  if a is not None and not is_mapped(a)}
        return sum(a.nbytes for a in arrays.values())

    def state_at(self, time: float, overrides: Mapping[str, ObjectPatch] | None = None) -> SceneState:
        """The scene at ``time`` seconds: its animations sampled there, then ``overrides`` (a pose
        given by name); raises UnknownObjectError naming an object the scene lacks."""
        return self.objects.posed(time, sample_animations(self.animations, time), overrides)


def _one_object_per_batch(batches: Sequence[MeshBatch]) -> list[SceneObject]:
    """A root object per batch, named after it (``name#2``, … where names repeat)."""
    objects, seen = [], set()
    for batch in batches:
        name, copy = batch.name, 1
        while name in seen:
            copy += 1
            name = f"{batch.name}#{copy}"
        seen.add(name)
        objects.append(SceneObject(name))
    return objects


def _measured(objects: Sequence[SceneObject], batches: Sequence[MeshBatch], boxes: np.ndarray) -> list[SceneObject]:
    """``objects`` with the bounds (2, 3) and triangle counts of the ``batches`` (boxes (B, 2, 3)) they own."""
    owners = np.array([b.owner for b in batches], np.int64)
    out = []
    for number, item in enumerate(objects):
        own = owners == number
        bounds = None if not own.any() else np.stack([boxes[own, 0].min(axis=0), boxes[own, 1].max(axis=0)])
        triangles = sum(b.triangle_count for b, mine in zip(batches, own, strict=True) if mine)
        out.append(dataclasses.replace(item, bounds=bounds, triangles=triangles))
    return out
